"""Workflows over the algorithm and the files: ``track`` (sequences) and ``export_result``."""
