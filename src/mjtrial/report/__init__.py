"""The report stage's outputs: the figures (`figures`) and the Markdown text (`text`).

`write_figures` draws from `summary.json` and the rollouts' recordings; `write_report` formats
every number from `summary.json`, `manifest.json`, the config and the model the manifest names.
"""

from typing import Any

from mjtrial.report.text import report_text, write_report

__all__ = ["report_text", "write_figures", "write_report"]


def __getattr__(name: str) -> Any:
    if name == "write_figures":
        # The figures are imported at first use: matplotlib costs a second to a process that
        # only formats text (verify recomputes the report's text, never its figures).
        from mjtrial.report.figures import write_figures

        return write_figures
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
