"""``leaffit-usd batch INPUT... -o OUTDIR``: convert many captures, in parallel, resumably."""
from __future__ import annotations

NAME = "batch"
HELP = "convert many captures (files, folders, a manifest) in parallel, resumably"
DESCRIPTION = """Convert every capture of the inputs into OUTDIR/<name>/<name>.usda, each in its own
process with its own log (OUTDIR/<name>/convert.log). OUTDIR/batch.json records each capture's
status, timings, counts and error line, rewritten atomically as captures finish: a killed batch
is resumed by running the same command again. A rerun skips captures whose outputs are complete
and whose input (SHA-256) and options are unchanged; --force converts them again.

INPUT: capture files, folders (searched recursively for .ply .spz .sog .splat), or a
manifest: .csv with a header row, or .json (a list of objects), with the columns input (required,
relative to the manifest) and optionally name, root, root_index, up, height, labels, edits,
up_axis, meters_per_unit (per-capture options). Names: the file's stem; for the INRIA layout
(<scene>/point_cloud/iteration_N/point_cloud.ply or <scene>/point_cloud.ply) the scene folder.

Every conversion option of 'convert' applies to every capture. Exit codes: 0 all converted (or
up to date), 1 any capture failed, 2 usage errors (nothing converted).

examples:
  leaffit-usd batch captures/ -o assets/
  leaffit-usd batch captures/ -o assets/ --jobs 2 --timeout 900 --height 0.5
  leaffit-usd batch manifest.csv -o assets/ --format usdz
  leaffit-usd batch captures/ -o /shared/assets --executor dask --scheduler tcp://head:8786"""
ORDER = 15


def _memory(text):
    import argparse

    from leaffit_usd.commands._args import pos_float

    t = text.strip().upper().removesuffix("B")
    mult = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    if t and t[-1] in mult:
        return int(pos_float(t[:-1]) * mult[t[-1]])
    try:
        return int(pos_float(t) * 2**30)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a size like 4G or 512M, got {text!r}") from None


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import pos_float, pos_int
    from leaffit_usd.commands.convert import add_options

    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="capture files, folders of captures, or a .csv/.json manifest")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                   help="output folder: OUTDIR/<name>/<name>.usda per capture, OUTDIR/batch.json")
    g = p.add_argument_group("batch")
    g.add_argument("--format", choices=["usda", "usdc", "usdz"], default="usda",
                   help="stage format of every capture (usda)")
    g.add_argument("-j", "--jobs", type=pos_int, default=None, metavar="N",
                   help="captures converted at once (default: cores / threads per job)")
    g.add_argument("--threads", type=pos_int, default=None, metavar="T",
                   help="torch/BLAS threads per capture (default: cores / jobs, at least 1)")
    g.add_argument("--timeout", type=pos_float, default=None, metavar="S",
                   help="seconds per capture; a capture still running then is killed and recorded "
                        "as failed (default: no limit)")
    g.add_argument("--max-memory", type=_memory, default=None, metavar="SIZE",
                   help="resident memory per capture, e.g. 4G; above it the capture is killed and "
                        "recorded as failed (default: no limit)")
    g.add_argument("--force", action="store_true",
                   help="convert again captures whose output is complete and up to date")
    g.add_argument("--executor", choices=["local", "dask"], default="local",
                   help="local processes (default) or a Dask cluster (extra [dask])")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://head:8786 (default: a local cluster of --jobs "
                        "workers); OUTDIR must be a path every worker sees")
    add_options(p)


def run(args) -> int:
    import sys
    from pathlib import Path

    from leaffit_usd.batch import BatchOptions, collect_captures, run_batch, summary_table
    from leaffit_usd.commands._args import parse_root, parse_up
    from leaffit_usd.commands.convert import options_from_args
    from leaffit_usd.errors import InputFileError, UserError

    for flag, v in (("--labels", args.labels), ("--edits", args.edits)):
        if v is not None:
            raise UserError(f"{flag} belongs to one capture: give it per capture in a manifest "
                            f"(column {flag[2:]})")
    if args.scheduler and args.executor != "dask":
        raise UserError("--scheduler needs --executor dask")
    outdir = Path(args.output)
    if outdir.exists() and not outdir.is_dir():
        raise UserError(f"{outdir}: exists and is not a folder")
    captures = collect_captures(args.inputs, exclude=outdir)
    for c in captures:                     # a manifest's up / root, parsed as --up / --root
        for key, parse in (("up", parse_up), ("root", parse_root)):
            if isinstance(c.overrides.get(key), str):
                try:
                    c.overrides[key] = parse(c.overrides[key])
                except UserError as e:
                    raise InputFileError(c.source, f"{c.path.name}: {key}: {e}") from None
    opts = BatchOptions(convert=options_from_args(args), stage_format=args.format, jobs=args.jobs,
                        threads=args.threads, timeout=args.timeout, max_memory=args.max_memory,
                        force=args.force, executor=args.executor, scheduler=args.scheduler,
                        progress=not args.quiet)
    summary = run_batch(captures, outdir, opts)
    if not args.quiet or summary.exit_code:
        print(summary_table(summary))
    sys.stdout.flush()
    if summary.interrupted:
        sys.stderr.write(f"leaffit-usd batch: interrupted ({summary.interrupted}); run the same "
                         "command again to finish\n")
        import signal
        return 128 + int(getattr(signal, summary.interrupted))
    return summary.exit_code
