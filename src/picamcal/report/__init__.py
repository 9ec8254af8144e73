"""The HTML report: one self-contained page of diagnostics, verdicts and (with test images) before/after evidence."""

from .html import write_report

__all__ = ["write_report"]
