"""sims: around the library, by role: file formats (io), the simulation, runners, the lab, the console and the CLI."""

__all__: list[str] = []
