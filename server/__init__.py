"""Glint's FastAPI service. It will never do numerical work itself: it talks to the
worker processes through one narrow interface (docs/architecture/index.md)."""
