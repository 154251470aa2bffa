"""Shared fixtures: the repository root as working directory (presets/ and shaders/ are found
there, as by the CLI), the CLI binary the Python results are compared with, and one small
session."""

from __future__ import annotations

import os
import pathlib
import subprocess

import pytest

import gilab

REPO = pathlib.Path(__file__).resolve().parents[2]
SIZE = (32, 32)


@pytest.fixture(scope="session", autouse=True)
def repo_cwd():
    os.chdir(REPO)
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
    yield REPO


@pytest.fixture(scope="session")
def gilab_bin() -> pathlib.Path:
    """The CLI built by `cargo build --release` (or GILAB_BIN): tests fail, never skip, without it."""
    path = pathlib.Path(os.environ.get("GILAB_BIN", REPO / "target" / "release" / "gilab"))
    assert path.is_file(), f"{path} is missing: run `cargo build --release` first"
    return path


@pytest.fixture(scope="session")
def run_cli(gilab_bin):
    def run(*args: str) -> str:
        done = subprocess.run(
            [str(gilab_bin), *args], cwd=REPO, capture_output=True, text=True, check=False
        )
        assert done.returncode == 0, f"gilab {' '.join(args)} failed:\n{done.stdout}\n{done.stderr}"
        return done.stdout

    return run


@pytest.fixture(scope="session")
def session():
    with gilab.Session("presets/cornell.toml", size=SIZE) as s:
        yield s
