"""Agents: TLPS, REPS and stable-baselines3 adapters behind one interface."""
