"""Tools for testing a deployment of agents: an attacker that floods a live socket with hostile frames."""
