"""agents: one agent per assembly (perception, local estimator, protocol participant) and module
agents. Depends on ``decentral`` and ``protocols``; never reads ground truth."""

__all__: list[str] = []

from agents.assembly import AgentConfig, AssemblyAgent, OwnStep  # noqa: E402

__all__ += ["AgentConfig", "AssemblyAgent", "OwnStep"]
