"""HRDIC in the SEM: spatial distortion, scan-line shifts and drift (docs/sem.md)."""
