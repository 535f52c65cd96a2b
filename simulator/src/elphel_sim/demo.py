"""`make demo`: the main job on the simulator, end to end, as far as the project goes.

Starts a simulated rig with `elphel-sim up`, talks to it only through the public
interfaces a user has (the REST API via the host library), and writes what it made under
``out/`` with a summary a person can read.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.camera import CameraClient
from elphel_host.preview import save_preview


@contextmanager
def simulated_rig(*, seed: int) -> Iterator[dict[str, Any]]:
    """Run `elphel-sim up --json` in a child process; yield its announcement."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "elphel_sim.cli", "up", "--json", "--seed", str(seed)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"elphel-sim up exited with code {proc.wait()} before serving")
        yield json.loads(line)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def step(message: str) -> None:
    print(f"[demo] {message}", flush=True)


def run(out: Path, *, seed: int) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {"seed": seed}
    step("starting the simulated rig (elphel-sim up)")
    with simulated_rig(seed=seed) as rig, CameraClient(rig["camera_url"], rig["token"]) as camera:
        step(f"camera daemon at {rig['camera_url']}")
        info = camera.info()
        summary["board"] = info["board"]
        summary["sensors"] = {
            str(p["port"]): p["sensor"]["model"] if p["sensor"] else None for p in info["ports"]
        }
        for port, model in summary["sensors"].items():
            step(f"port {port}: {model or 'no sensor'} (detected over simulated I2C)")

        t0 = time.monotonic()
        frame = camera.capture(0)
        elapsed = time.monotonic() - t0
        tif = out / "frame.tif"
        tif.write_bytes(frame.tiff)
        png = save_preview(frame.image, out / "frame.png", bayer=frame.metadata.get("bayer"))
        h, w = frame.image.shape
        step(f"captured frame {frame.frame}: {w}x{h} {frame.image.dtype} in {elapsed:.1f} s")
        summary["capture"] = {
            "file": str(tif),
            "preview": str(png),
            "shape": [h, w],
            "dtype": str(frame.image.dtype),
            "mean_dn": round(float(np.mean(frame.image)), 1),
            "seconds": round(elapsed, 2),
            "metadata": frame.metadata,
        }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    step(f"wrote {tif}, {png} and {out / 'summary.json'}")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="elphel-sim-demo", description="Run the main job on the simulator."
    )
    p.add_argument("--out", type=Path, default=Path("out"), help="output folder (default out/)")
    p.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    args = p.parse_args(argv)
    try:
        run(args.out, seed=args.seed)
    except (OSError, RuntimeError, ValueError) as e:
        print(f"demo: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
