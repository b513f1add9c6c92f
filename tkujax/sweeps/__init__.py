"""The sweep machinery: a spec's pushes run in chunks that survive a crash, and the records
they leave.

  sweep.py           `tkujax sweep`: chunked, resumable, sharded sweeps; load()
  sweep_folder.py    a folder belongs to one sweep: the claim and the spec check under one lock
  sweep_hash.py      the sweep's identity: when a rerun resumes a sweep
  sweep_robot.py     which robot a sweep's records were made on
  chunks.py          chunk files: atomic writes, checksums, the manifest
  chunk_program.py   the compiled MJX program of a chunk, and its record inputs
  mujoco_chunk.py    a chunk on MuJoCo C
  lane_stream.py     lanes that refill as pushes are decided early
  early.py           early decisions: a push is decided when the robot falls or settles
  record_schema.py   the manifest's versioned record schema
  provenance.py      who made a chunk: backend, device, commit, run
  replay.py          `tkujax replay`: one record re-simulated (replay_exact.py: bit for bit)
  table_export.py    `tkujax export`: Parquet or CSV records
  progress.py        progress bars and the status log of long runs
  compile_cache.py   the persistent compilation cache
"""
