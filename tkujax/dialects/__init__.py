"""The spec dialects: the sweep spec (TOML) and the validation every dialect shares.

  sweep_spec.py      sweep specs: schema, parsing, expansion into push records
  program_keys.py    the [sweep] keys that choose how a sweep's program runs
  step_table.py      [step]: commanded recovery steps
  fpga_table.py      [fpga]: the fixed-point controller's checks
  push_limits.py     the limits a parsed spec is checked against
  validation.py      values, ranges and error messages shared by every dialect (the tune and
                     calibrate dialects live with their studies: tkujax.studies.tune.tune_spec,
                     tkujax.studies.calibrate.calibrate_spec)
"""
