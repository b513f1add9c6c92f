"""`tkujax export DIR --format parquet|csv [--out FILE]`: a finished sweep's records as one file."""

from __future__ import annotations


def _cmd_export(args) -> int:
    from tkujax.sweeps.table_export import export_records

    path = export_records(args.dir, args.out, fmt=args.format,
                          allow_incomplete=args.allow_incomplete)
    print(path)
    return 0


def add_export_command(sub) -> None:
    """export: the records of a finished sweep folder as one Parquet (or CSV) file."""
    p = sub.add_parser("export", help="a finished sweep's records (all chunks) as one Parquet "
                                      "or CSV file, the manifest in its metadata")
    p.add_argument("dir", help="a complete sweep output folder")
    p.add_argument("--format", choices=["parquet", "csv"], default="parquet",
                   help="parquet (default; the manifest in the schema metadata) or csv (the "
                        "manifest beside it as FILE.manifest.json)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="file to write (default: DIR.parquet or DIR.csv beside the folder)")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="export an incomplete sweep's chunks done, the manifest's "
                        "exported_state saying how many (default: refused)")
    p.set_defaults(func=_cmd_export)
