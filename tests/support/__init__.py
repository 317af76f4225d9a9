"""Helpers shared by the test tiers (not tests): import them as ``from tests.support.<module> import ...``."""
