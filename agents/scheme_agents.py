"""The former name of agents.scheme_process (the patrol and central agent processes): kept so old imports work."""

from agents.scheme_process import (DEPLOY_REPEATS, DEPLOY_WAIT_FRAC, SCHEMES, CentralAgentNode, PatrolAgentNode,
                                   make_agent_node)

__all__ = ["DEPLOY_REPEATS", "DEPLOY_WAIT_FRAC", "SCHEMES", "PatrolAgentNode", "CentralAgentNode", "make_agent_node"]
