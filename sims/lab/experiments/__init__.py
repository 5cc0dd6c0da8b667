"""The seed papers' experiments reproduced on rendered data, and perception test scenes."""

__all__: list[str] = []
