"""Markdown tables that go into README.md and docs/ (the results pages), written from evaluations' results.json.

One module per page family, all writing through :func:`blenav.eval.common.write_text` (atomic) and, where a page or
the README keeps a generated block between hand-written text, through the one splice helper
(:func:`blenav.reporting.splice.splice`):

* :mod:`~blenav.reporting.realwalks`: the ILC 2.0 real-walk pages, summary and README table;
* :mod:`~blenav.reporting.realwalks_priors`: the learned map prior with two priors on the real walks;
* :mod:`~blenav.reporting.merge`: several evaluations in one table, and the leaderboard over a fleet;
* :mod:`~blenav.reporting.feng_rtt`: the Feng et al. real-RTT page;
* :mod:`~blenav.reporting.crf_tables`: the CRF experiments' Table I / Fig. 12;
* :mod:`~blenav.reporting.backend_robust`: the back-end on buildings and channels it was not tuned to.

Layer: above :mod:`blenav.eval` (it reads the evaluations' results and uses their helpers), below the command lines
(:mod:`blenav.cli.realwalks`, :mod:`blenav.cli.tables`), which parse the arguments and compose configs.
"""


def num(v, nd: int = 2, none: str = "-") -> str:
    """``v`` with ``nd`` decimals, or ``none`` where a results.json holds null (a statistic over nothing: strict JSON
    writes a NaN as null, :func:`blenav.eval.common.finite_json`)."""
    return none if v is None else f"{v:.{nd}f}"
