"""Report: the results table beside the paper's, and figures (PNG, Agg backend)."""

from tactile_bench.report.table import PAPER_TABLE, format_table_for_terminal, results_markdown

__all__ = ["PAPER_TABLE", "format_table_for_terminal", "results_markdown"]
