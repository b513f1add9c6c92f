"""A robot walking from its controller's CPG: `tkujax walk` (walk.py) and pushes placed by gait
phase (walk_push.py)."""
