"""The agent: one identical process per robot, no leader (see agent.main)."""
