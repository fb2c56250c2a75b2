"""Capture layouts (one module per layout), merged in one table."""
