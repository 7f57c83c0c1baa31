"""The report stage's outputs: the figures (`figures`) and the Markdown text (`text`).

`write_figures` draws from `summary.json` and the rollouts' recordings; `write_report` formats
every number from `summary.json`, `manifest.json`, the config and the model the manifest names.
"""

from mjtrial.report.figures import write_figures
from mjtrial.report.text import report_text, write_report

__all__ = ["report_text", "write_figures", "write_report"]
