"""What a finished sweep says: stability maps, the comparison of two controllers, and the
capturability theory the maps are checked against.

  maps.py            `tkujax map`: stability maps and capture regions from a sweep
  map_cells.py       the maps' binned statistics: cells, fall boundaries, fall by phase
  compare.py         `tkujax compare`: fall-rate cells and the no-harm verdict
  compare_report.py  the comparison's files
  capturability.py   LIP capturability bounds
"""
