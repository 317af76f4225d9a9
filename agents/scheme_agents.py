"""The former name of agents.scheme_process (the patrol and central agent processes): kept so old imports work."""

from agents.scheme_process import SCHEMES, CentralAgentNode, PatrolAgentNode, make_agent_node

__all__ = ["SCHEMES", "PatrolAgentNode", "CentralAgentNode", "make_agent_node"]
