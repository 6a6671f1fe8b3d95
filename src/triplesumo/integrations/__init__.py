"""Adapters to outside libraries (optional imports): ``sb3`` (Stable-Baselines3)."""
