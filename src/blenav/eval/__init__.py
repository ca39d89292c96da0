"""Evaluation harness: run methods over sessions and runs, compute metrics, write results (blenav-eval)."""
