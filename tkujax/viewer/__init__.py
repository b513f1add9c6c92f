"""`tkujax view`: a browser replay viewer of a sweep's records.

geometry.py: a MuJoCo model's geoms as meshes and their poses per frame; playback.py: which
records, and each re-simulated record as a `PushScene` (pure data); server.py: the viser page
(`ReplayViewer`). Only server.py imports viser (the `view` extra).
"""
