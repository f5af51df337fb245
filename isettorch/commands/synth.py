"""``isettorch synth``: write a synthetic camera-pair dataset as checksummed, resumable shards.

Example::

    isettorch synth --config configs/synth/default.yaml --out data/synth --count 10000 --workers 2
    torchrun --nproc-per-node 4 -m isettorch.cli synth --config CFG --out DIR --count N   # ranks split shards
"""

from __future__ import annotations

from .._progress import add_quiet_argument


def register(sub) -> None:
    p = sub.add_parser("synth", help="write synthetic (noisy raw, targets, metadata) training pairs as shards")
    p.add_argument("--config", default=None, help="YAML config (keys of isettorch.data.config.SYNTH_DEFAULTS); "
                                                  "default: the built-in defaults")
    p.add_argument("--out", required=True, help="output folder (shards, sidecars, manifest.json)")
    p.add_argument("--count", type=int, default=None,
                   help="number of items in the whole dataset (required; with --verify optional, checked against "
                        "the manifest)")
    p.add_argument("--shard", type=int, default=0, help="this invocation's part (0-based), with --num-shards")
    p.add_argument("--num-shards", type=int, default=1, help="number of parts the files are dealt into")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes (default 0: the main process)")
    add_quiet_argument(p, "--no-progress")
    p.add_argument("--verify", action="store_true", help="only check the checksums of an existing output")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys
    from pathlib import Path

    from .._yaml import check_yaml_mapping
    from ..data.config import load_config
    from ..data.writer import unfinished, verify_dataset, write_dataset
    from ._outputs import check_dir

    if args.verify:
        if not Path(args.out).is_dir():
            raise FileNotFoundError(f"--out: no such dataset folder {args.out!r} to --verify")
        if not (Path(args.out) / "manifest.json").is_file():
            why = unfinished(args.out) or " (not a dataset written by isettorch synth)"
            raise ValueError(f"out: {args.out} has no manifest.json{why}")
        problems = verify_dataset(args.out)
        if problems and problems[0].startswith(("manifest.json: unreadable", "manifest.json: malformed")):
            raise ValueError(f"out: {args.out}/{problems[0]}")
        if args.count is not None:  # checked against the manifest (it was required and then ignored)
            import json

            count = json.loads((Path(args.out) / "manifest.json").read_text()).get("count")
            if count != args.count:
                problems.append(f"count: the dataset holds {count} items, --count {args.count}")
        for line in problems:
            print(line, file=sys.stderr)
        print("ok" if not problems else f"{len(problems)} problem(s)")
        return 0 if not problems else 1
    # bad input raises ValueError naming the option ("count: ..." is shown as "--count: ...", isettorch.cli)
    if args.count is None:
        raise ValueError("count: expected the number of items in the whole dataset (--count N)")
    if args.num_shards < 1:
        raise ValueError(f"num_shards: expected a number of parts >= 1, got {args.num_shards}")
    if args.config:  # UTF-8 YAML holding a mapping, or empty (the defaults); load_config reports a missing file
        check_yaml_mapping(args.config, "config", "a mapping of settings (keys of "
                           "isettorch.data.config.SYNTH_DEFAULTS)", empty_ok=True)
    cfg = None
    if args.config:  # its keys and values, named with the file ('foo: unknown config key' did not say which)
        from ..data.config import merge_config

        try:
            cfg = load_config(args.config)
            merge_config(cfg)
        except ValueError as err:
            raise ValueError(f"config: {args.config}: {err}") from err
    check_dir(args.out, "out")  # a file, or a place without write permission: named before any work
    manifest = write_dataset(cfg, args.out, args.count, shard=args.shard, num_shards=args.num_shards,
                             workers=args.workers, progress=not args.quiet)
    done = len(manifest["shards"])
    print(f"{done}/{manifest['num_files']} shards in {args.out}" + (" (complete)" if manifest["complete"] else ""))
    return 0
