"""File formats of the public contract (reading with validation, writing atomically)."""

from sims.io.atomic import write_atomic, write_json_atomic

__all__ = ["write_atomic", "write_json_atomic"]
