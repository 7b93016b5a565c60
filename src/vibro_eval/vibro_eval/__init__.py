"""Evaluation harness: ``vibro prove`` (blind proof of the discrepancy analysis), truth scoring, PySINDy baseline."""
