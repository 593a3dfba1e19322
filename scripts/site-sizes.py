#!/usr/bin/env python3
"""The web site's download sizes against their record (web/sizes.json).

    scripts/site-sizes.py            # after `trunk build --release`: fail if either grew
    scripts/site-sizes.py --update   # record the current sizes (a deliberate change)

Two figures, gzipped at level 6 as a static host serves them: the wasm module with its
JavaScript glue, and the default bundle (models/default). Each fails when it grows past its
recorded value by more than the record's tolerance (a build on another machine may differ
by a few bytes); the first view's share of the bundle (the files the progressive load
fetches first) is printed beside them.
"""
import gzip
import json
import pathlib
import sys

root = pathlib.Path(__file__).resolve().parent.parent
dist = root / "dist"
record_path = root / "web" / "sizes.json"


def gz(path: pathlib.Path) -> int:
    return len(gzip.compress(path.read_bytes(), compresslevel=6, mtime=0))


def measure() -> dict:
    wasm = [dist / "pvrnn-explorer_bg.wasm", dist / "pvrnn-explorer.js"]
    missing = [str(p) for p in wasm if not p.is_file()]
    if missing:
        sys.exit(f"no {', '.join(missing)}: run `trunk build --release` first")
    bundle_dir = dist / "models" / "default"
    bundle = sorted(p for p in bundle_dir.iterdir() if p.is_file())
    manifest = json.loads((bundle_dir / "bundle.json").read_text())
    dataset = json.loads((bundle_dir / "dataset.json").read_text())
    first = {"bundle.json", "dataset.json", manifest["model"], dataset["sequences"][0]["file"]}
    first.update(manifest.get("runs", [])[:1])
    return {
        "wasm_gzip_bytes": sum(gz(p) for p in wasm),
        "bundle_gzip_bytes": sum(gz(p) for p in bundle),
        "first_view_gzip_bytes": sum(gz(p) for p in bundle if p.name in first),
    }


def main() -> None:
    now = measure()
    if "--update" in sys.argv[1:]:
        record = {"tolerance": 0.002, **{k: now[k] for k in ("wasm_gzip_bytes", "bundle_gzip_bytes")}}
        record_path.write_text(json.dumps(record, indent=2) + "\n")
        print(f"recorded in {record_path.relative_to(root)}: {record}")
        return
    record = json.loads(record_path.read_text())
    failed = False
    for key in ("wasm_gzip_bytes", "bundle_gzip_bytes"):
        limit = record[key] * (1 + record["tolerance"])
        verdict = "ok" if now[key] <= limit else "GREW"
        print(f"{key}: {now[key]:,} (recorded {record[key]:,}) {verdict}")
        failed |= now[key] > limit
    print(f"first view (model, one sequence, the standard runs): {now['first_view_gzip_bytes']:,} of {now['bundle_gzip_bytes']:,} bytes")
    if failed:
        sys.exit(
            "the site grew past its recorded size: make it smaller, or record the new size on "
            "purpose with `scripts/site-sizes.py --update` and say why in the commit"
        )


main()
