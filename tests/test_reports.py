"""The reports and the README's numbers: one protocol version per report, the current one or said.

- Every report in reports/ states its protocol in its first lines (``Protocol:``): a benchmark suite's
  name and version, which must be the suite's current ``PROTOCOL_VERSION`` unless the line says
  plainly that it is not the current one; or that it is not a suite's protocol (its own, stated).
- The suites' own reports (reports/lasa.md, reports/robottasks.md) are at the current version and
  hold every learner and the DMP in both splits; a learner added after their run may instead have its
  own run beside them (reports/lasa_<learner>.json and .md), at the current version, in both splits.
- Every number the README quotes in a paragraph or list item that links a report appears in one of
  the reports it links, and each report it links is current; the "Measured results" section quotes
  no number without such a link.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from lfd.bench import protocol as lasa_protocol
from lfd.bench import robottasks
from lfd.bench.spaces import bench_learners

ROOT = Path(__file__).resolve().parents[1]
REPORTS = ROOT / "reports"
CURRENT = {"lasa": lasa_protocol.PROTOCOL_VERSION, "robottasks": robottasks.PROTOCOL_VERSION}
#: "(lasa, version 3)", "LASA protocol version 2", "robot tasks, version 1"
VERSION = re.compile(r"\b(lasa|robottasks|robot tasks|RoboTasks9)\b[^.\n]{0,24}?\bversion (\d+)", re.IGNORECASE)
NOT_CURRENT = "not the current"
HEAD_LINES = 12
NUMBER = re.compile(r"(?<![\w.])\d+(?:[.,]\d+)*(?![\w])")
LINK = re.compile(r"\(?(?:\.\./)?reports/([\w.-]+\.md)\)?|\]\(([\w.-]+\.md)\)")


def _suite(name: str) -> str:
    return "lasa" if name.lower() == "lasa" else "robottasks"


def protocol_line(text: str) -> str | None:
    """The first line among the report's first ``HEAD_LINES`` that states its protocol."""
    return next((line for line in text.splitlines()[:HEAD_LINES] if "Protocol:" in line), None)


@pytest.mark.parametrize("report", sorted(p.name for p in REPORTS.glob("*.md")))
def test_every_report_states_its_protocol_and_it_is_current_or_says_not(report: str) -> None:
    text = (REPORTS / report).read_text()
    line = protocol_line(text)
    assert line is not None, f"{report}: no 'Protocol:' line in its first {HEAD_LINES} lines"
    for name, version in VERSION.findall(line):
        suite = _suite(name)
        if int(version) != CURRENT[suite]:
            assert NOT_CURRENT in line, f"{report}: {suite} version {version}, current {CURRENT[suite]}, not said"
    assert VERSION.search(line) or "not a benchmark suite's" in line, line


@pytest.mark.parametrize("report,results,suite", [("lasa.md", "lasa_results.json", "lasa"),
                                                  ("robottasks.md", "robottasks.json", "robottasks")])
def test_the_suites_reports_are_current_with_every_learner_in_both_splits(report: str, results: str,
                                                                           suite: str) -> None:
    runs = {results: report}
    for learner in bench_learners():
        own = f"{suite}_{learner}"
        if (REPORTS / f"{own}.json").is_file():
            runs[f"{own}.json"] = f"{own}.md"
    found: dict[str, str] = {}
    for results_file, report_file in runs.items():
        line = protocol_line((REPORTS / report_file).read_text())
        assert line is not None and [(_suite(n), int(v)) for n, v in VERSION.findall(line)] == \
            [(suite, CURRENT[suite])], report_file
        data = json.loads((REPORTS / results_file).read_text())
        assert data["protocol"]["version"] == CURRENT[suite]
        assert data["splits"] == ["in-sample", "held-out"], results_file
        for learner in data["learners"]:
            both = data["summary"][learner]
            assert both["in-sample"] is not None and both["held-out"] is not None, learner
            assert both["in-sample"]["units"] == both["held-out"]["units"] == \
                len(data["shapes" if suite == "lasa" else "tasks"]), learner
            found.setdefault(learner, results_file)
    assert set(found) == set(bench_learners()), f"learners with no current run in both splits: " \
        f"{sorted(set(bench_learners()) - set(found))}"


def _blocks(markdown: str) -> list[str]:
    """Paragraphs and list items, code blocks and inline code removed."""
    text = re.sub(r"```.*?```", "", markdown, flags=re.DOTALL)
    text = re.sub(r"`[^`]*`", "", text)
    blocks: list[str] = []
    for para in re.split(r"\n\s*\n", text):
        items = re.split(r"\n(?=- )", para)
        blocks.extend(item for item in items if item.strip())
    return blocks


def _numbers(text: str) -> set[str]:
    return {n.replace(",", "") for n in NUMBER.findall(text)}


def _linked(block: str) -> list[str]:
    return [a or b for a, b in LINK.findall(block)]


def readme_claims() -> list[tuple[str, list[str], set[str]]]:
    """(block, linked reports, numbers) for every README block that links a report."""
    out = []
    for block in _blocks((ROOT / "README.md").read_text()):
        linked = [r for r in _linked(block) if (REPORTS / r).is_file()]
        if linked:
            out.append((block, linked, _numbers(re.sub(r"\[[^\]]*\]\([^)]*\)", "", block))))
    return out


def test_the_readme_quotes_only_numbers_found_in_the_current_reports_it_links() -> None:
    claims = readme_claims()
    assert len(claims) >= 5
    for block, linked, numbers in claims:
        texts = {r: (REPORTS / r).read_text() for r in linked}
        found = set().union(*(_numbers(t) for t in texts.values()))
        missing = sorted(numbers - found)
        assert not missing, f"README numbers not in {', '.join(linked)}: {missing}\n{block[:300]}"
        for r, t in texts.items():
            line = protocol_line(t)
            assert line is not None and NOT_CURRENT not in line, f"the README cites {r}, which is not current"


def test_the_measured_results_quote_no_number_without_a_report() -> None:
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Measured results", 1)[1].split("\n## ", 1)[0]
    for block in _blocks(section)[1:]:      # the first paragraph says where the numbers come from
        if _numbers(re.sub(r"\[[^\]]*\]\([^)]*\)", "", block)) - {"2"}:
            assert any((REPORTS / r).is_file() for r in _linked(block)), f"no report linked:\n{block[:300]}"
