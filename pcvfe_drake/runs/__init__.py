"""Runs: scenarios, drive logs, the run log, summary and figures."""
