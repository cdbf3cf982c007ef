"""Offline evaluation: Table I of the PF-DOA paper reproduced on committed data.

``evaluate(config, out=..., plots_dir=...)`` runs every experiment (see
:mod:`pfdoa.evaluation.experiments`), writes the Markdown report
(:mod:`pfdoa.evaluation.report`) and the PNG plots (:mod:`pfdoa.evaluation.plots`).
The ``pfdoa eval`` command is a thin wrapper.
"""

from __future__ import annotations

import os
from pathlib import Path

from pfdoa.evaluation.experiments import EvalConfig, EvalResults, run_all
from pfdoa.evaluation.report import fit_tables, render, targets


def evaluate(cfg: EvalConfig, *, out: Path | None = None, plots_dir: Path | None = None,
             command: str = "pfdoa eval", progress: bool = True) -> tuple[EvalResults, str]:
    """Run the evaluation; write the report to ``out`` and plots to ``plots_dir`` if given."""
    res = run_all(cfg, progress=progress)
    plot_refs: list[str] = []
    if plots_dir is not None:
        from pfdoa.evaluation.plots import make_plots

        made = make_plots(res, Path(plots_dir))
        base = Path(out).resolve().parent if out is not None else Path.cwd()
        plot_refs = [os.path.relpath(p.resolve(), base).replace(os.sep, "/") for p in made]
    text = render(res, command, fit_tables(res), plot_refs)
    if out is not None:
        from pfdoa.outfiles import write_whole

        Path(out).parent.mkdir(parents=True, exist_ok=True)
        write_whole(out, text, "--out")  # atomic for a file; a device or FIFO written through
    return res, text


__all__ = ["EvalConfig", "EvalResults", "evaluate", "run_all", "targets"]
