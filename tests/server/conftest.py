"""Server fixtures live in tests/conftest.py (shared with tests/web)."""
