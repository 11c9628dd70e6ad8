"""Pack the newest checkpoint of each run under ROOT/.checkpoints into at most 7 bundles of 15.5 MB (63 MB together),
the runs that got furthest first; say in the log which runs did not fit."""

import json
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

root, out = Path(sys.argv[1]), Path(os.environ["OUT"])
packs = Path("/tmp/packs")
packs.mkdir(exist_ok=True)
zstd = shutil.which("zstd")
runs = []
for spec in sorted(root.glob(".checkpoints/*/*/*/spec.json")):
    folder = spec.parent
    try:
        step = (folder / "latest").read_text().strip()
        state = json.loads((folder / step / "checkpoint.json").read_text())
    except OSError as error:
        print("no checkpoint:", folder, error)
        continue
    runs.append((state["num_timesteps"], folder, step))
runs.sort(key=lambda run: -run[0])
bundles: list[list[Path]] = [[] for _ in range(7)]
sizes = [0] * 7
for steps, folder, step in runs:
    rel = folder.relative_to(root)
    name = f"{folder.parent.name}__{folder.name}.tar" + (".zst" if zstd else ".xz")
    members = f"{rel}/spec.json {rel}/latest {rel}/{step}"
    squeeze = f"{zstd} -q -6 -T2 --long=27" if zstd else "xz -T2 -1"
    subprocess.run(f"tar -C {root} -cf - {members} | {squeeze} > {packs / name}", shell=True, check=True)
    size = (packs / name).stat().st_size
    fits = [i for i in range(7) if sizes[i] + size <= 15_500_000]
    if not fits or sum(sizes) + size > 63_000_000:
        print(f"LEFT OUT {rel} at {steps} steps ({size} bytes)")
        continue
    sizes[fits[0]] += size
    bundles[fits[0]].append(packs / name)
    print(f"packed {rel} at {steps} steps ({size} bytes) into bundle {fits[0]}")
for i, files in enumerate(bundles):
    if files:
        with tarfile.open(out / f"bundle{i}.tar", "w") as tar:
            for file in files:
                tar.add(file, arcname=file.name)
print("bundles (bytes):", sizes)
