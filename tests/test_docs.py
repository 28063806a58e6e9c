"""What a newcomer reads: the README's first screen, links that resolve, the documentation and
licences that travel with the wheel."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from mocapfix.apps.main import DOCS
from mocapfix.apps.main import main as mocapfix

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def test_the_first_screen_has_the_two_commands_and_the_next_three():
    first = "\n".join(README.splitlines()[:40])
    for command in ("make demo", "make test", "mocapfix fix", "mocapfix render", "mocapfix fit"):
        assert command in first, command


def test_the_readme_points_at_nothing_a_wheel_user_lacks():
    # the README is also the package's description on an index
    for checkout_only in ("../shared", ".venv/bin/python", "pip install -e"):
        assert checkout_only not in README


def test_every_relative_link_resolves():
    pages = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
    broken = []
    for page in pages:
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if "://" not in target and not (page.parent / target).exists():
                broken.append(f"{page.name}: {target}")
    assert not broken


def test_mocapfix_docs_names_the_installed_pages(capsys):
    assert mocapfix(["docs"]) == 0
    out = capsys.readouterr().out
    assert str(DOCS) in out and "models.md" in out and "training.md" in out
    assert DOCS == ROOT / "mocapfix" / "docs" and (ROOT / "docs").resolve() == DOCS


def test_bench_results_hold_at_most_37_files():
    # what today's docs cite, nothing superseded (git history keeps those); 28 since correction_carry,
    # 30 since issue 47's scaling and search benchmarks, 31 with issue 48's Human3.6M protocol, 32-34 with
    # issue 49's keypoint layouts, exchanges and flips, 35-36 with issue 48's fix with a correction
    # trained on the capture (Bandai, Human3.6M), 37 with issue 49's real keypoint recordings
    assert len(list((ROOT / "bench" / "results").iterdir())) <= 37


def test_the_wheel_carries_the_docs_the_model_cards_and_both_licences(tmp_path):
    # built from a copy of what the wheel is made of: setuptools leaves build/ and *.egg-info
    # beside the sources it builds, and no test writes into the checkout
    source = tmp_path / "source"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info")
    shutil.copytree(ROOT / "mocapfix", source / "mocapfix", ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, source / name)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-q", "-w", tmp_path],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("mocapfix-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        metadata = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert {f"mocapfix/docs/{p.name}" for p in DOCS.glob("*.md")} <= names
    assert "mocapfix/pretrained/LICENSE" in names
    assert "License-Expression: MIT AND CC-BY-NC-4.0" in metadata
    assert any(n.endswith("licenses/LICENSE") for n in names)
