"""Agents: one module per algorithm, plus the pieces they share."""
