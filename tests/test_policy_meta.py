"""flashnav.policy_meta: the exported-policy metadata, read and checked without torch."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from flashnav.policy_meta import METADATA_KEY, POLICY_FORMAT_VERSION, parse_metadata
from flashnav.version import __version__


def test_parse_metadata_reads_and_names_the_file_on_bad_input():
    meta = {"format_version": POLICY_FORMAT_VERSION, "obs_dim": 37}
    assert parse_metadata("p.onnx", json.dumps(meta)) == meta
    assert parse_metadata("p.pt", json.dumps(meta).encode()) == meta
    with pytest.raises(ValueError, match=f"^p.pt: no FlashNav metadata \\({METADATA_KEY}\\)"):
        parse_metadata("p.pt", None)
    with pytest.raises(ValueError, match="^p.pt: .* is not valid JSON"):
        parse_metadata("p.pt", "{")
    with pytest.raises(ValueError, match="^p.pt: .* lacks an integer obs_dim"):
        parse_metadata("p.pt", json.dumps({"format_version": 1, "obs_dim": "37"}))
    newer = json.dumps({"format_version": POLICY_FORMAT_VERSION + 1, "obs_dim": 37})
    with pytest.raises(ValueError, match=f"this FlashNav {__version__} reads <= {POLICY_FORMAT_VERSION}"):
        parse_metadata("p.pt", newer)


def test_policy_meta_imports_and_checks_without_torch():
    # a robot-side runtime reads policy metadata without torch: importing and checking must not load it
    newer = json.dumps({"format_version": POLICY_FORMAT_VERSION + 1, "obs_dim": 3})
    code = textwrap.dedent(f"""
        import sys
        from flashnav.policy_meta import parse_metadata
        try:
            parse_metadata("p.pt", {newer!r})
        except ValueError as exc:
            assert "this FlashNav {__version__} reads" in str(exc), exc
        else:
            raise AssertionError("a newer format version was accepted")
        assert "torch" not in sys.modules, "flashnav.policy_meta imported torch"
        print("ok")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
