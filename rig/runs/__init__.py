"""Runs and recordings: the run engine, run folders, recordings, results and their provenance."""
