"""Figures in the README and docs/ prose, tied to the stored results they quote.

A figure in prose is a number with a result unit: ``751 / 805 µm``, ``1.5 mm``, ``28x``, ``12 %``
or a count ``4 of the 12``.  Every such figure outside a generated block (``<!-- BEGIN name -->`` …
``<!-- END name -->``, see ``tools/doc_sections.py``), a code fence or an inline code span is one of:

* **marked**: ``<!-- fig NAME -->751 / 805<!-- /fig --> µm``.  ``NAME`` is a quantity of
  :data:`REGISTRY`, whose function reads the stored result (``test/data/reference_metrics.json``,
  ``docs/scanner_study/table.csv``, ...) and formats it.  ``tools/gen_doc_figures.py`` rewrites
  every marked figure from the stored results; :func:`check` reports a marked figure whose text
  differs from its stored value (stale), an unknown name, and two marks of one name with different
  text (a contradiction, whichever file they are in);
* **quoted**: the same figure text stands in a generated block of the docs (a table regenerated
  from stored results; the prose repeats one of its cells);
* **allowlisted**: a model input or physical constant of the paper (:data:`INPUTS`: short, each
  with its reason);
* **unverified**: on the ledger ``docs/figures_unverified.txt`` (the figures that were in the docs
  when this check was introduced and are not yet tied to a result).  The ledger only shrinks:
  :func:`check` fails on a figure that is none of the above and on a ledger line whose figure is
  gone, and the test caps the ledger's length.

Everything here reads files only; nothing is re-run.
"""

from __future__ import annotations

import csv
import json
import re
import statistics
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEDGER = "docs/figures_unverified.txt"

# ---------------------------------------------------------------------------------------------
# Stored results


@cache
def _reference_runs(root: Path) -> dict[str, dict[str, float]]:
    runs: dict[str, dict[str, float]] = json.loads(
        (root / "test" / "data" / "reference_metrics.json").read_text(encoding="utf-8"))["runs"]
    return runs


@cache
def _scanner_rows(root: Path, study: str = "scanner_study") -> tuple[dict[str, str], ...]:
    with (root / "docs" / study / "table.csv").open(newline="", encoding="utf-8") as fh:
        return tuple(csv.DictReader(fh))


def _um(x_m: float) -> str:
    return f"{x_m * 1e6:.0f}"


def _ref_values(root: Path, scenario: str, metric: str) -> list[float]:
    runs = _reference_runs(root)
    vals = [runs[f"{scenario}/{s}"][f"{metric}_m"] for s in range(5) if f"{scenario}/{s}" in runs]
    if not vals:
        raise KeyError(f"no stored run of {scenario} with {metric}_m in test/data/reference_metrics.json")
    return vals


def _ref(root: Path, m: re.Match[str]) -> str:
    """``ref.SCENARIO.METRIC[.mean|.worst]``: seeds 0-4 of a shipped scenario, µm (mean / worst)."""
    vals = _ref_values(root, m["scenario"], m["metric"])
    mean, worst = statistics.fmean(vals), max(vals)
    if m["stat"] == "mean":
        return _um(mean)
    if m["stat"] == "worst":
        return _um(worst)
    if m["stat"] == "worst_mm":
        return f"{worst * 1e3:.1f}"
    return f"{_um(mean)} / {_um(worst)}"


def _cell(root: Path, study: str, hardware: str, cell: str, pair: str) -> dict[str, str]:
    tw, pw, lat = (float(x) / 1e3 for x in cell.split("-"))
    for r in _scanner_rows(root, study):
        if (r["hardware"] == hardware and r["pair"] == pair
                and abs(float(r["tracking_window_s"]) - tw) < 1e-9
                and abs(float(r["propulsion_window_s"]) - pw) < 1e-9
                and abs(float(r["latency_s"]) - lat) < 1e-9):
            return r
    raise KeyError(f"docs/{study}/table.csv has no row {hardware} {cell} ms {pair}")


def _scanner_cell(root: Path, m: re.Match[str]) -> str:
    """``scanner.HARDWARE.TW-PW-LAT.PAIR.tracking_max``: one cell of the scanner study, µm (mean / worst)."""
    r = _cell(root, "scanner_study", m["hardware"], m["cell"], m["pair"])
    return f"{_um(float(r['tracking_max_mean_m']))} / {_um(float(r['tracking_max_worst_m']))}"


def _pair_rows(root: Path, hardware: str, pair: str) -> list[dict[str, str]]:
    rows = [r for r in _scanner_rows(root) if r["hardware"] == hardware and r["pair"] == pair]
    if not rows:
        raise KeyError(f"docs/scanner_study/table.csv has no rows of {hardware} {pair}")
    return rows


def _scanner_pair(root: Path, m: re.Match[str]) -> str:
    """``scanner.HARDWARE.PAIR.{worst_max_mm,cells}``: over every cell of a pair (worst of the worst, mm; count)."""
    rows = _pair_rows(root, m["hardware"], m["pair"])
    if m["what"] == "cells":
        return str(len(rows))
    return f"{max(float(r['tracking_max_worst_m']) for r in rows) * 1e3:.2f}"


def _scanner_wins(root: Path, m: re.Match[str]) -> str:
    """``scanner.HARDWARE.A_vs_B.cells_won``: cells where pair A's worst tracking max is below B's."""
    key = ("tracking_window_s", "propulsion_window_s", "latency_s")
    b = {tuple(r[k] for k in key): float(r["tracking_max_worst_m"]) for r in _pair_rows(root, m["hardware"], m["b"])}
    won = sum(1 for r in _pair_rows(root, m["hardware"], m["a"])
              if r["status"] == "ok" and float(r["tracking_max_worst_m"]) < b[tuple(r[k] for k in key)])
    return str(won)


@dataclass(frozen=True)
class Quantity:
    """A family of quantity names (a regex with named groups), the stored result it reads, and how."""

    pattern: re.Pattern[str]
    source: str
    read: Callable[[Path, re.Match[str]], str]


_ID = r"[a-z0-9_]+"
#: Every quantity a doc may mark.  Formats: µm as integers, mm with the digits the name says.
REGISTRY: tuple[Quantity, ...] = (
    Quantity(re.compile(rf"ref\.(?P<scenario>{_ID})\.(?P<metric>{_ID}?)(?:\.(?P<stat>mean|worst|worst_mm))?"),
             "test/data/reference_metrics.json", _ref),
    Quantity(re.compile(rf"scanner\.(?P<hardware>{_ID})\.(?P<cell>\d+-\d+-\d+)\.(?P<pair>{_ID})\.tracking_max"),
             "docs/scanner_study/table.csv", _scanner_cell),
    Quantity(re.compile(rf"scanner\.(?P<hardware>{_ID})\.(?P<a>{_ID})_vs_(?P<b>{_ID})\.cells_won"),
             "docs/scanner_study/table.csv", _scanner_wins),
    Quantity(re.compile(rf"scanner\.(?P<hardware>{_ID})\.(?P<pair>{_ID})\.(?P<what>worst_max_mm|cells)"),
             "docs/scanner_study/table.csv", _scanner_pair),
)


def stored_value(name: str, root: Path = ROOT) -> str:
    """The text quantity ``name`` has in the stored results (KeyError naming what is missing)."""
    for q in REGISTRY:
        m = q.pattern.fullmatch(name)
        if m:
            return q.read(root, m)
    raise KeyError(f"unknown quantity {name!r} (tools/docs_figures.py REGISTRY)")


# ---------------------------------------------------------------------------------------------
# Finding figures

MARK = re.compile(r"<!-- fig (?P<name>[\w.\-]+) -->(?P<text>.*?)<!-- /fig -->")
_NUM = r"\d+(?:,\d{3})*(?:\.\d+)?"
#: A number (or a range / pair of numbers) with a result unit, or a count "N of (the) M".
FIGURE = re.compile(
    rf"(?<![\w.,/-])(?:{_NUM}(?:\s*(?:/|\u2013|-|to)\s*{_NUM})*\s*(?:µm|um|mm|\u00d7|x|%)(?![\w])"
    rf"|\d+ of (?:the )?\d+(?![\w.]))")
_CODE = re.compile(r"`[^`]*`")
_LINK = re.compile(r"\]\([^)]*\)|https?://\S+")
_BEGIN = re.compile(r"^<!-- BEGIN ([\w-]+) -->")
_END = re.compile(r"^<!-- END ([\w-]+) -->")

#: Figures that are inputs, not results: the paper's model and the sequence, quoted as configured.
#: Each is matched as "figure text | the words after it".  Keep it short: a result never goes here.
INPUTS: dict[str, str] = {
    "100 µm noise": "the imager's noise, an input of Table III",
    "100 um noise": "the imager's noise, an input of Table III",
    "5 % V_f": "the paper's model error on the blood velocity, an input",
    "5 % velocity": "the paper's model error on the blood velocity, an input",
    "5 % model": "the paper's model error on the blood velocity, an input",
    "5 % error": "the paper's model error on the blood velocity, an input",
    "5 % too": "the paper's model error on the blood velocity, an input",
    "< 150 um": "the paper's claimed bound, quoted",
    "150 um after": "the paper's claimed bound, quoted",
    "< 10 um": "the paper's claimed bound, quoted",
    # the scenario's geometry and the paper's inputs (Table I's vessel, X0, the aberrant measurements)
    "10 mm /s). The error": "the flow velocity of the case the text describes, an input",
    "1 mm ), the injection": "the reference's first anchor X0, an input",
    "1 mm ) and is announced": "the paper's aberrant measurements (1 mm for 20 ms), an input",
    "1 mm , 20 ms outlier": "the paper's aberrant measurements (1 mm for 20 ms), an input",
    "1 mm offset": "the paper's aberrant measurements (1 mm for 20 ms), an input",
    "1 mm for 20 ms": "the paper's aberrant measurements (1 mm for 20 ms), an input",
    "1 mm downstream": "the paper's aberrant measurements (1 mm for 20 ms), an input",
    "1 mm above the axis": "the paper's reference height, an input",
    "1 mm vessel": "Table I's vessel diameter, an input",
    "1 mm ) |": "Table I's vessel diameter (a table's row label), an input",
    "10 mm ) |": "Table I's vessel diameter (a table's row label), an input",
    "1 mm before the node": "where Fig. 6's bifurcation profiles are sampled, an input",
    "10 mm into": "the symmetric bifurcation's position, an input",
    "1 mm of the wall": "the near-wall region the wall field resolves, an input",
    "250 um bead": "Table III's bead diameter, an input",
    "1 um -20 mm": "the importer's radius limits, an input",
    # thresholds a test or a check applies (what a run must stay within), not what a run gave
    "10 mm ) from the reference": "the divergence bound max(10 D, 10 mm), a threshold",
    "250 um of the fault-free": "the fault test's tracking threshold",
    "1 mm ) in": "the lost-track threshold of the scanner study",
    "1 mm . The insert": "the scanner study's tracking target",
    "100 x U_sat": "the hostile test controller's command range, an input",
    "2 x U_sat": "a deliberately broken clamp (the check of the invariant test), an input",
    # a real-time factor asked for (vesselbot run --real-time-factor): what a run held is a result, what it is asked is not
    "0.05x": "a real-time factor asked for, an input",
    "1x": "a real-time factor asked for, an input",
    "50x": "a real-time factor asked for, an input",
}


@dataclass(frozen=True)
class Figure:
    """One figure of a doc: where it stands, its text, and (if marked) the quantity it names."""

    file: str
    line: int
    text: str
    context: str
    name: str | None = None

    @property
    def key(self) -> str:
        """Its ledger line: the figure and the words around it (no file, no line: text moves)."""
        return f"{self.text} | {self.context}"


def docs_files(root: Path = ROOT) -> list[Path]:
    """README.md and the top-level pages of docs/."""
    return [p for p in [root / "README.md", *sorted((root / "docs").glob("*.md"))] if p.is_file()]


def _normal(s: str) -> str:
    return re.sub(r"\s+", " ", s.replace("\u00a0", " ")).strip()


def scan(path: Path, root: Path = ROOT) -> tuple[list[Figure], list[Figure], set[str]]:
    """The marked and the unmarked prose figures of one file, and the texts of its generated blocks' cells."""
    rel = path.relative_to(root).as_posix()
    marked: list[Figure] = []
    unmarked: list[Figure] = []
    generated: set[str] = set()
    block: str | None = None
    fence = False
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if block is None and (b := _BEGIN.match(line)):
            block = b.group(1)
            continue
        if block is not None:
            if _END.match(line):
                block = None
            else:
                generated.update(_normal(m.group(0)) for m in FIGURE.finditer(_CODE.sub(" ", line)))
            continue
        if line.lstrip().startswith(("```", "~~~")):
            fence = not fence
            continue
        if fence or (line.lstrip().startswith("<!--") and "fig " not in line):
            continue
        for m in MARK.finditer(line):
            marked.append(Figure(rel, i, m["text"], _normal(line[m.end():m.end() + 30]), m["name"]))
        prose = _LINK.sub(" ", _CODE.sub(" ", MARK.sub(" ", line)))
        for m in FIGURE.finditer(prose):
            before = _normal(prose[max(0, m.start() - 30):m.start()])
            after = _normal(prose[m.end():m.end() + 30])
            unmarked.append(Figure(rel, i, _normal(m.group(0)), f"{before} … {after}"))
    return marked, unmarked, generated


def _allowlisted(f: Figure) -> bool:
    after = f.context.split(" … ", 1)[1]
    return any(f"{f.text} {after}".startswith(k) for k in INPUTS)


@dataclass(frozen=True)
class Problem:
    """One finding: file, line, what, and (for figures) the quantity, the doc's text and the stored value."""

    file: str
    line: int
    kind: str
    name: str = ""
    doc: str = ""
    stored: str = ""

    def __str__(self) -> str:
        detail = f" {self.name}: doc says {self.doc!r}, stored {self.stored!r}" if self.name else f" {self.doc}"
        return f"{self.file}:{self.line}: {self.kind}:{detail}"


def read_ledger(root: Path = ROOT) -> list[str]:
    """The ledger's figure lines (comments and blank lines dropped)."""
    path = root / LEDGER
    if not path.is_file():
        return []
    return [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]


def collect(files: Iterable[Path], root: Path = ROOT) -> tuple[list[Figure], list[Figure], set[str]]:
    """Every file's marked and unmarked figures, and the figure texts of every generated block."""
    marked: list[Figure] = []
    unmarked: list[Figure] = []
    generated: set[str] = set()
    for p in files:
        mk, um, gen = scan(p, root)
        marked += mk
        unmarked += um
        generated |= gen
    return marked, unmarked, generated


def unverified(unmarked: list[Figure], generated: set[str]) -> list[Figure]:
    """The unmarked figures that are neither quoted from a generated block nor allowlisted."""
    return [f for f in unmarked if f.text not in generated and not _allowlisted(f)]


def check(root: Path = ROOT, files: Iterable[Path] | None = None) -> list[Problem]:
    """Every stale, unknown or contradicting mark, and every unsupported figure not on the ledger."""
    files = docs_files(root) if files is None else list(files)
    marked, unmarked, generated = collect(files, root)
    problems: list[Problem] = []
    first: dict[str, Figure] = {}
    for f in marked:
        assert f.name is not None
        try:
            stored = stored_value(f.name, root)
        except KeyError as e:
            problems.append(Problem(f.file, f.line, "unknown quantity", f.name, f.text, str(e)))
            continue
        if f.text != stored:
            problems.append(Problem(f.file, f.line, "stale figure", f.name, f.text, stored))
        other = first.setdefault(f.name, f)
        if other.text != f.text:
            problems.append(Problem(f.file, f.line, f"contradicts {other.file}:{other.line}", f.name, f.text,
                                    other.text))
    ledger = read_ledger(root)
    left = list(ledger)
    for f in unverified(unmarked, generated):
        if f.key in left:
            left.remove(f.key)
        else:
            problems.append(Problem(f.file, f.line, "figure no stored result supports (mark it, or qualify it)",
                                    doc=f"{f.text!r} in {f.context!r}"))
    for key in left:
        problems.append(Problem(LEDGER, ledger.index(key) + 1, "ledger line whose figure is gone (delete it)",
                                doc=key))
    return problems


def regenerate(text: str, root: Path = ROOT) -> str:
    """``text`` with every marked figure rewritten from the stored results (an unknown name: KeyError)."""
    return MARK.sub(lambda m: f"<!-- fig {m['name']} -->{stored_value(m['name'], root)}<!-- /fig -->", text)


def suspects(root: Path = ROOT) -> list[tuple[str, list[Figure]]]:
    """Unmarked figures with the same words before them and the same unit but different numbers.

    A discovery aid (``tools/gen_doc_figures.py --suspects``), not a check: "worst 474 um" in one
    page and "worst 515 um" in another may be the same quantity gone stale, or two cells.
    """
    groups: dict[str, list[Figure]] = {}
    _, unmarked, _ = collect(docs_files(root), root)
    for f in unmarked:
        words = re.findall(r"[A-Za-z_()]+", f.context.split(" … ", 1)[0])[-3:]
        unit = re.sub(r"[\d.,\s/\u2013-]|to", "", f.text)
        if len(words) == 3:
            groups.setdefault(f"{' '.join(words).lower()} [{unit}]", []).append(f)
    return [(k, fs) for k, fs in sorted(groups.items())
            if len({f.text for f in fs}) > 1 and len({f.file for f in fs}) > 1]
