"""Value types and primitives every other layer builds on (no algorithm here)."""
