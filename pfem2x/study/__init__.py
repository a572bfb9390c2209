"""Parameter studies: ``pfem2x study`` shows what accuracy costs in time.

A study runs the cartesian product of ``--vary KEY=V1,V2,...`` lists of a scene
(``--vary K1,K2=[a1,b1],[a2,b2]``: keys varied together, one axis), each variant in
its own process (``python -m pfem2x run SCENE --set ... --out
DIR/variants/<slug> --quiet --overwrite``), and tabulates, per variant, the
varied keys, the scene's error metrics (every numeric scalar of the summary's
``metrics``), wall and CPU seconds, steps, the child's peak memory, status and
exit code in ``study.csv``, ``study.json`` and ``study.md``, with two plots:
error against wall time (one curve per frame, the Pareto front marked) and
error against Δt and against the Courant number.

The driver is serial and never imports DOLFINx or MPI; every variant is checked
with :func:`pfem2x.scene.load_scene` before anything runs or is written. It is
resumable: a variant whose folder holds a ``summary.json`` with status ``ok`` or
``diverged`` and the same resolved ``scene.toml`` is not run again.

Exit codes: 0 the study ran (failed or diverged variants are rows with their
status), 2 bad input (one ``error:`` line on stderr naming the key; nothing run
or written), 130 interrupted.

Modules: :mod:`~pfem2x.study.plan` (the input and the variants),
:mod:`~pfem2x.study.children` (the child processes), :mod:`~pfem2x.study.rows`
(table rows, metric, Pareto front), :mod:`~pfem2x.study.report` (csv, json,
markdown), :mod:`~pfem2x.study.plots`, :mod:`~pfem2x.study.driver`
(:func:`run_study`) and :mod:`~pfem2x.study.command` (the sub-command).
"""

from pfem2x.study.children import DONE_STATUSES, RUN_RECORD
from pfem2x.study.command import add_study_parser, study_main
from pfem2x.study.driver import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OK,
    STUDY_MARKER,
    StudyResult,
    run_study,
)
from pfem2x.study.plan import (
    StudyError,
    Variant,
    parse_axis,
    parse_vary,
    plan_study,
    split_values,
)
from pfem2x.study.plots import write_plots
from pfem2x.study.report import BASE_COLUMNS, write_markdown, write_tables
from pfem2x.study.rows import DEFAULT_METRICS, choose_metric, pareto_front

__all__ = [
    "BASE_COLUMNS",
    "DEFAULT_METRICS",
    "DONE_STATUSES",
    "EXIT_BAD_INPUT",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "RUN_RECORD",
    "STUDY_MARKER",
    "StudyError",
    "StudyResult",
    "Variant",
    "add_study_parser",
    "choose_metric",
    "pareto_front",
    "parse_axis",
    "parse_vary",
    "plan_study",
    "run_study",
    "split_values",
    "study_main",
    "write_markdown",
    "write_plots",
    "write_tables",
]
