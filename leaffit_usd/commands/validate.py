"""``leaffit-usd validate FILE...``: USD's validators plus the LeafFit layout checks."""
from __future__ import annotations

import json
import sys

NAME = "validate"
HELP = "check a LeafFit USD file (pxr.UsdValidation + layout rules)"
DESCRIPTION = """Run every validator registered with USD's validation framework (pxr.UsdValidation,
for each leafRepresentation variant, payloads loaded) and LeafFit's own layout checks (one
template Mesh, one instance per leaf, K x 3 floats per instance, materials, provenance ...).

Findings print as  SEVERITY rule  path: message.
Exit status: 0 no errors; 1 at least one error (with --strict: or warning); 2 unreadable file."""
ORDER = 60


def add_arguments(p) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help=".usda / .usdc / .usdz stage(s)")
    p.add_argument("--strict", action="store_true", help="warnings fail too")
    p.add_argument("--no-usd", action="store_true", help="skip USD's own validators (layout rules only)")
    p.add_argument("--json", metavar="OUT", help="also write the findings as JSON ('-' = stdout)")


def run(args) -> int:
    from leaffit_usd.io_util import atomic_write_bytes
    from leaffit_usd.usd.validate import validate_file

    reports = [validate_file(f, run_usd=not args.no_usd) for f in args.files]
    failed = False
    for r in reports:
        for f in r.findings:
            if f.severity != "info" or not args.quiet:
                print(f"{r.file}: {f}")
        bad = r.failed(args.strict)
        failed |= bad
        if not args.quiet or bad:
            print(f"{r.file}: {'FAILED' if bad else 'ok'} ({r.count('error')} errors, "
                  f"{r.count('warning')} warnings)")
    if args.json:
        data = json.dumps([r.to_dict() for r in reports], indent=2).encode()
        if args.json == "-":
            sys.stdout.write(data.decode() + "\n")
        else:
            atomic_write_bytes(args.json, data)
    return 1 if failed else 0
