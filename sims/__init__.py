"""MJX scenes for jaxtrack: simulated humanoid and person-following episodes.

This is the only package that imports MuJoCo and MJX.
"""
