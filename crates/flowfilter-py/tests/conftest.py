"""Shared fixtures of the Python package's tests: paths, the CLI, a synthesised BOP scene."""

import json
import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
FIXTURES = ROOT / "fixtures"
PEERS = FIXTURES / "peers" / "registration"
SHARED = ROOT.parent / "shared" / "data"
YCB_VIDEO = SHARED / "ycb-video" / "0001"


def find_cli():
    """The `flowfilter` command line: $FLOWFILTER_CLI, else the workspace's debug or release build."""
    given = os.environ.get("FLOWFILTER_CLI")
    if given:
        if not pathlib.Path(given).is_file():
            raise RuntimeError(f"FLOWFILTER_CLI={given}: no such file")
        return pathlib.Path(given)
    for profile in ["debug", "release"]:
        path = ROOT / "target" / profile / "flowfilter"
        if path.is_file():
            return path
    return None


@pytest.fixture(scope="session")
def cli():
    """Run the CLI with arguments; returns its stdout. Skips when no build exists (CI sets FLOWFILTER_CLI)."""
    path = find_cli()
    if path is None:
        pytest.skip("no flowfilter CLI build (cargo build -p flowfilter, or set FLOWFILTER_CLI)")

    def run(*args):
        done = subprocess.run([str(path), *map(str, args)], capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            raise AssertionError(f"flowfilter {' '.join(map(str, args))} failed:\n{done.stderr}")
        return done.stdout

    run.path = path
    return run


@pytest.fixture(scope="session")
def bop_scene(tmp_path_factory, cli):
    """A synthesised BOP scene (procedural box, NP3, turntable 0, 4 and 12 degrees, sensor effects)."""
    out = tmp_path_factory.mktemp("bop")
    cli("synth", "--procedural", "box", "--format", "bop", "--cameras", "NP3", "--angles", "0,4,12", "--seed", "3", "--out", out)
    scene = out / "000003"
    assert (scene / "scene_gt.json").is_file()
    return scene


@pytest.fixture(scope="session")
def ycb_video():
    """The shared real YCB-Video frames; skipped with a message when ../shared is absent."""
    if not YCB_VIDEO.is_dir():
        pytest.skip(f"{YCB_VIDEO} is absent: the real-frame tests need ../shared beside the repository")
    return YCB_VIDEO


def peer_cases():
    """The recorded peer results (tools/peers/registration_peers.py)."""
    return json.loads((PEERS / "results.json").read_text())["cases"]

