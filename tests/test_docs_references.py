"""Every design reference in the code resolves inside the repository: a decision D<n> to its heading in
docs/decisions.md, ``baselines.md §x`` to docs/baselines.md, an env module's ``SPEC §x`` to its env's spec in
docs/envs/, and nothing points at design documents outside the repository."""

from __future__ import annotations

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
CODE = [p for package in ("jaxmac", "envs_jax") for p in (ROOT / package).rglob("*.py")]


def headings(doc: str) -> set[str]:
    """The section labels of a document: ``D7``, ``1.4``, ``12.10`` ... from its ``#`` headings."""
    labels = set()
    for line in (ROOT / "docs" / doc).read_text().splitlines():
        match = re.match(r"#+\s+(?:§\s*)?(D\d+|\d+(?:\.\d+)*)\b", line)
        if match:
            labels.add(match.group(1))
    return labels


def cited(pattern: str, files=CODE) -> dict[str, set[str]]:
    found: dict[str, set[str]] = {}
    for path in files:
        for label in re.findall(pattern, path.read_text()):
            found.setdefault(label, set()).add(str(path.relative_to(ROOT)))
    return found


def test_every_decision_cited_has_a_heading():
    decisions = headings("decisions.md")
    missing = {d: files for d, files in cited(r"\b(D\d{1,2})\b").items() if d not in decisions}
    assert not missing, missing
    assert {"D0", "D9", "D20"} <= decisions  # the check reads the headings at all


def test_every_baselines_section_cited_exists():
    sections = headings("baselines.md")
    missing = {s: f for s, f in cited(r"baselines\.md\s*§\s*(\d+(?:\.\d+)*)").items() if s not in sections}
    assert not missing, missing


def test_every_spec_section_cited_exists_in_its_envs_spec():
    missing, checked = {}, 0
    for env in ("boxpushing", "overcooked", "warehouse"):
        files = [p for p in CODE if env in p.relative_to(ROOT).parts[-1] or env in p.relative_to(ROOT).parts[:-1]]
        sections = headings(f"envs/{env}.md")
        for label, where in cited(r"SPEC\s*§\s*(\d+(?:\.\d+)*)", files).items():
            checked += 1
            if label not in sections:
                missing[f"{env} §{label}"] = where
    assert not missing, missing
    assert checked > 20  # the envs cite their specs throughout


def test_no_reference_to_documents_outside_the_repository():
    outside = cited(r"(shared/(?:design|reference|paper)\S*|DECISIONS\.md|BASELINES\.md|HYPERPARAMS\.md)")
    assert not outside, outside
