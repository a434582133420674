"""Policies, training and evaluation for gym_gridloc (see the README)."""
