"""Baselines the benchmarks compare against (not part of the leaffit_usd package)."""
