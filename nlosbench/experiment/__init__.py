"""Experiments: config schema, run context, runner and reports."""
