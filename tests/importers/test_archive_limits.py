"""Issue 28, section 2: archives given to ``blenav-import ilc20`` are read one member at a time, each member's
declared size bounded before it is read (BLENAV_MAX_ARCHIVE_MEMBER_MB) and the archive's expansion bounded
(BLENAV_MAX_ARCHIVE_RATIO); link and special members are not read and are counted in the report."""

from __future__ import annotations

import gzip
import io
import stat
import tarfile
import zipfile

import pytest

from blenav import limits
from blenav.errors import ImportError_
from blenav.importers import run_import

from ilc20_helpers import walk_lines, write_floor, write_walk

BIG = "mall/F1/path_data_files/big.txt"


def forbid_reads(monkeypatch):
    """From now on, fail if a member is opened for reading (a refusal must come from its declared size, before
    anything of it is read)."""
    def refuse(*a, **k):
        raise AssertionError("a member was opened for reading")

    monkeypatch.setattr(tarfile.TarFile, "extractfile", refuse)
    monkeypatch.setattr(zipfile.ZipFile, "open", refuse)
    monkeypatch.setattr(zipfile.ZipFile, "read", refuse)


def _zeros_tgz(path, size: int, name: str = BIG):
    """A .tar.gz holding one member of ``size`` zero bytes (compresses about 1000 times)."""
    with tarfile.open(path, "w:gz") as tf:
        info = tarfile.TarInfo(name)
        info.size = size
        tf.addfile(info, io.BytesIO(bytes(size)))
    return path


def test_a_tar_member_declared_too_large_is_refused_unread(tmp_path, monkeypatch):
    # the finding: a 9 MB .tar.gz with one 2 GB member was read whole (MemoryError). Only the header is needed
    # to refuse it: this archive declares 2 GiB and holds 1 kB of it.
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as tf:
        info = tarfile.TarInfo(BIG)
        info.size = 2 << 30
        tf.addfile(info)  # header only
    raw.write(bytes(1024))
    tgz = tmp_path / "bomb.tar.gz"
    tgz.write_bytes(gzip.compress(raw.getvalue()))
    forbid_reads(monkeypatch)
    with pytest.raises(ImportError_) as e:
        run_import("ilc20", tgz, tmp_path / "out")
    assert str(e.value) == (f"{tgz}:{BIG}: archive member of 2,048.0 MiB, larger than the 256 MiB a member may have "
                            "(set BLENAV_MAX_ARCHIVE_MEMBER_MB to allow more); not read")
    assert not (tmp_path / "out").exists()


def test_a_member_over_a_lowered_limit_is_refused_in_tar_and_zip(tmp_path, monkeypatch):
    monkeypatch.setenv("BLENAV_MAX_ARCHIVE_MEMBER_MB", "1")
    tgz = _zeros_tgz(tmp_path / "a.tar.gz", 3 << 20)
    zp = tmp_path / "a.zip"
    with zipfile.ZipFile(zp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(BIG, bytes(3 << 20))
    forbid_reads(monkeypatch)
    for src in (tgz, zp):
        with pytest.raises(ImportError_) as e:
            run_import("ilc20", src, tmp_path / f"out_{src.suffix}")
        assert str(e.value).startswith(f"{src}:{BIG}: archive member of 3.0 MiB, larger than the 1 MiB"), str(e.value)


def test_a_compression_bomb_is_refused_by_its_ratio(tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "ARCHIVE_RATIO_FREE_MB", 0.0)  # the 64 MiB any archive may expand to, lowered
    tgz = _zeros_tgz(tmp_path / "r.tar.gz", 2 << 20)  # 2 MiB in about 2 kB
    zp = tmp_path / "r.zip"
    with zipfile.ZipFile(zp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(BIG, bytes(2 << 20))
    forbid_reads(monkeypatch)
    for src in (tgz, zp):
        ratio = (2 << 20) / src.stat().st_size
        assert ratio > 200
        with pytest.raises(ImportError_) as e:
            run_import("ilc20", src, tmp_path / f"out_{src.suffix}")
        msg = str(e.value)
        assert msg.startswith(f"{src}:{BIG}: the archive's members expand to 2.0 MiB by this one, over 200 times the "
                              "archive's") and "compression bomb" in msg, msg


def _floor_files(tmp_path):
    d = write_floor(tmp_path / "raw")
    write_walk(d, "walkA", walk_lines())
    return d.parent  # the site folder "mall"


def test_link_members_are_counted_in_the_report_not_followed(tmp_path):
    site = _floor_files(tmp_path)
    tgz = tmp_path / "links.tar.gz"
    with tarfile.open(tgz, "w:gz") as tf:
        tf.add(site, arcname="mall")
        for name, kind, target in (("mall/F1/path_data_files/evil.txt", tarfile.SYMTYPE, "/etc/passwd"),
                                   ("mall/F1/path_data_files/hard.txt", tarfile.LNKTYPE, "mall/F1/floor_info.json"),
                                   ("mall/F1/dev", tarfile.CHRTYPE, "")):
            info = tarfile.TarInfo(name)
            info.type, info.linkname = kind, target
            tf.addfile(info)
    rep = run_import("ilc20", tgz, tmp_path / "out")
    assert rep.sessions == 1
    note = [n for n in rep.notes if "archive member" in n]
    assert note == ["3 archive member(s) not read: links or special files (mall/F1/path_data_files/evil.txt, "
                    "mall/F1/path_data_files/hard.txt, mall/F1/dev)"], rep.notes
    assert note[0] in str(rep)

    zp = tmp_path / "links.zip"
    with zipfile.ZipFile(zp, "w") as zf:
        for p in sorted(site.rglob("*")):
            zf.write(p, p.relative_to(site.parent).as_posix())
        link = zipfile.ZipInfo("mall/F1/path_data_files/evil.txt")
        link.create_system = 3
        link.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(link, "/etc/passwd")
    rep = run_import("ilc20", zp, tmp_path / "out_zip")
    assert rep.sessions == 1
    assert "1 archive member(s) not read: links or special files (mall/F1/path_data_files/evil.txt)" in rep.notes


def test_the_real_archives_members_pass_the_default_limits(raw_dir):
    """The ILC 2.0 sample (../shared): every member's declared size and each archive's expansion within the
    defaults, checked from the headers alone; the figures docs/security.md and limits.py quote (largest member
    4.1 MB, expansion 5.1-5.6 times: B1 5.07, F1 5.60, F2 5.26; far below 256 MiB and 200 times)."""
    from blenav.importers._common import ArchiveBudget

    largest, ratios = 0, []
    for tgz in sorted((raw_dir / "ilc20").glob("*.tar.gz")):
        budget = ArchiveBudget(tgz)
        with tarfile.open(tgz, "r|gz") as tf:
            for m in tf:
                if m.isfile():
                    budget.take(m.name, m.size)
                    largest = max(largest, m.size)
        ratios.append(budget.total / tgz.stat().st_size)
    assert len(ratios) == 3 and round(largest / 1e6, 1) == 4.1, largest
    assert (round(min(ratios), 1), round(max(ratios), 1)) == (5.1, 5.6), ratios


def _zip_with(method: int, flag_bits: int = 0, compress_type: int | None = None, garble: int | None = None) -> bytes:
    """A zip of one path file, its header altered: general-purpose flags, the compression method number, or 30
    bytes of its compressed stream garbled from byte ``garble`` on."""
    import struct

    raw = io.BytesIO()
    with zipfile.ZipFile(raw, "w", method) as zf:
        zf.writestr(BIG, bytes(range(256)) * 400)
    b = bytearray(raw.getvalue())
    cd = b.rfind(b"PK\x01\x02")  # the central directory's entry
    if flag_bits:
        struct.pack_into("<H", b, 6, flag_bits)
        struct.pack_into("<H", b, cd + 8, flag_bits)
    if compress_type is not None:
        struct.pack_into("<H", b, 8, compress_type)
        struct.pack_into("<H", b, cd + 10, compress_type)
    if garble is not None:
        start = 30 + len(BIG) + garble
        b[start:start + 30] = bytes(x ^ 0x5A for x in b[start:start + 30])
    return bytes(b)


@pytest.mark.parametrize("fault, data, message", [
    ("deflate", lambda: _zip_with(zipfile.ZIP_DEFLATED, garble=0), "not a readable zip archive (Error -3 while "
     "decompressing data: invalid block type)"),
    ("lzma", lambda: _zip_with(zipfile.ZIP_LZMA, garble=60), "not a readable zip archive (Corrupt input data)"),
    ("method", lambda: _zip_with(zipfile.ZIP_STORED, compress_type=99), "not a readable zip archive (That "
     "compression method is not supported)"),
    ("encrypted", lambda: _zip_with(zipfile.ZIP_DEFLATED, flag_bits=1), f"{BIG}: archive member is encrypted (a "
     "password-protected zip); not read"),
])
def test_a_zip_the_library_cannot_decompress_is_one_error_naming_it(tmp_path, fault, data, message):
    # each ended as a traceback (zlib.error, LZMAError, NotImplementedError, RuntimeError), not as the CLI's one line
    zp = tmp_path / f"{fault}.zip"
    zp.write_bytes(data())
    with pytest.raises(ImportError_) as e:
        run_import("ilc20", zp, tmp_path / "out")
    assert str(e.value).startswith(f"{zp}: {message}" if message.startswith("not") else f"{zp}:{message}"), str(e.value)
    assert not (tmp_path / "out").exists()
