"""blenav-calibrate's --out never replaces a file of the dataset it reads (red-team of issue 28, sec. 3)."""

from __future__ import annotations

import pytest

from blenav.cli.calibrate import main


@pytest.mark.parametrize("where", ["sessions/s0/rssi.csv", "sessions/s0"])
def test_out_that_is_a_dataset_file_or_a_folder_is_refused(tmp_path, capsys, where):
    """``--out SESSION/rssi.csv`` wrote the fit's YAML over the session's readings (the dataset then failed
    blenav-validate: [missing-column]); a folder ended as IsADirectoryError. Now one line, exit 1, nothing
    written."""
    data = tmp_path / "data"
    (data / "sessions" / "s0").mkdir(parents=True)
    (data / "sessions" / "s0" / "rssi.csv").write_text("t,anchor_id,rssi\n")
    with pytest.raises(SystemExit) as e:
        main([str(data), "--out", str(data / where)])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 1 and "\n" not in err
    assert err.startswith(f"blenav-calibrate: error: --out {data / where} is a folder or a file of the dataset")
    assert (data / "sessions" / "s0" / "rssi.csv").read_text() == "t,anchor_id,rssi\n"
