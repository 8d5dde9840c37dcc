"""Benchmarks and evaluations behind ``torch4dtree benchmark``: curves (vs fdasrsf) and trees (vs the paper)."""
