"""Experiments that evaluate tasks: leave-one-out type accuracy, robustness, reports.

Modules are imported by name (e.g. ``from torchhrc.experiments.loo import
leave_one_subject_out``) so that importing the package stays cheap.
"""

from __future__ import annotations

__all__: list[str] = []
