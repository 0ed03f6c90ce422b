"""Sphinx extension: the `result` role, a number read from a committed run's files when the site builds.

A page never types a number a run produced; it names where the number is::

    {result}`FILE[SELECTOR] EXPRESSION :FORMAT`

- ``FILE``: a path under ``results/``, a ``.csv`` or a ``.json`` file.
- ``SELECTOR`` (CSV): conditions on columns, comma-separated, ``column=value`` (also ``!=``, ``<``, ``<=``,
  ``>``, ``>=``; numbers compare as numbers, so ``theta=0.79`` matches 0.7899999999999999); it must pick
  exactly one row, or several when the expression takes their ``min``, ``max`` or ``mean``.
  (JSON): a dotted path to an object, list indices as numbers: ``[studies.00-bounds]``; in a list,
  ``key=value`` picks the object holding that value (``[knobs.prune.points.value=light_c]``); a key may
  hold dots (``[results.noise.AWGN(sigma=0.025)]``). Left out: the whole file.
- ``EXPRESSION``: a column (a key), or arithmetic over the row's columns: ``1e4 * mse`` (m² → cm²),
  ``1e4 * 10 ** crlb_lower``, ``mse / crlb``, ``abs(...)``; ``min(...)``, ``max(...)``, ``mean(...)`` over
  the selected rows (with several arguments: over them, in one row). A text cell prints as it stands.
- ``FORMAT``: ``.Ns``, N significant digits with trailing zeros kept (0.030, 230, 5.1e6: plain from 1e-4
  to 1e5), or any Python format spec (``.2f``); left out, a whole number prints as it is and any other
  with 3 significant digits. Exponents print unpadded (``1.1e-5``), a negative with a minus sign (−),
  infinity as ∞, true/false as yes/no. ``:time`` prints seconds as a duration (40.6 s, 14 min 22 s),
  ``:head`` a text cell up to its first colon, ``:dagger`` † where a note column is not empty.

A missing file, an unknown column or key, a selector matching no row or too many, or a value that is not
a number where arithmetic needs one is an error naming the role: the build fails (it runs with ``-W``).
Examples::

    {result}`quick/00-bounds/bounds.csv[noise_index=0, theta_object_position=1.3] log10_crlb :.2f`
    {result}`repro_pi_table/table/summary.csv[name=mle-adam, theta_object_position>=1] max(mse_over_crlb) :.2s`
    {result}`quick/machine.json seconds_total :time`

tests/test_docs_results.py resolves every role of the pages without a build, and fails when a number a run
printed is typed into the pages or the README instead.
"""
from __future__ import annotations

import ast
import csv
import json
import math
import operator
import re
from functools import cache
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[2] / "results"
_SPEC = re.compile(r"^\s*(?P<file>[^\s\[]+)(?:\[(?P<sel>[^\]]*)\])?\s+(?P<expr>[^:]+?)\s*(?::(?P<fmt>\S*))?\s*$")
_COND = re.compile(r"^\s*(?P<col>[\w.-]+)\s*(?P<op>!=|<=|>=|=|<|>)\s*(?P<val>.*?)\s*$")
_OPS = {"=": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le, ">": operator.gt,
        ">=": operator.ge}
_BIN = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
        ast.Pow: operator.pow}
_AGG = {"min": min, "max": max, "mean": lambda v: sum(v) / len(v)}


class ResultError(ValueError):
    """A quoted file, row, column or value that is not there."""


@cache
def _load(path: Path, stamp: tuple[int, int]):
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            return list(csv.DictReader(f))
    if path.suffix == ".json":
        return json.loads(path.read_text())
    raise ResultError(f"{path.name}: only .csv and .json files are read")


def _number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def _matches(cell, op: str, want: str) -> bool:
    a, b = _number(cell), _number(want)
    if a is not None and b is not None:
        if math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12):  # 0.7899999999999999 is 0.79
            a = b
        return _OPS[op](a, b)
    if op not in ("=", "!="):
        raise ResultError(f"{op} compares numbers; {cell!r} or {want!r} is not one")
    return (str(cell) == want) == (op == "=")


def _rows(data, sel: str) -> list[dict]:
    if isinstance(data, list):  # CSV rows
        conds = [c for c in (sel or "").split(",") if c.strip()]
        rows = data
        for c in conds:
            m = _COND.match(c)
            if not m:
                raise ResultError(f"selector {c.strip()!r}: write column=value (or !=, <, <=, >, >=)")
            if data and m["col"] not in data[0]:
                raise ResultError(f"no column {m['col']!r} (columns: {', '.join(data[0])})")
            rows = [r for r in rows if _matches(r[m["col"]], m["op"], m["val"])]
        if not rows:
            raise ResultError(f"no row where {sel}")
        return rows
    node, keys = data, [k for k in (sel or "").split(".") if k]
    while keys:
        key = keys.pop(0)
        if isinstance(node, list) and key.lstrip("-").isdigit() and -len(node) <= int(key) < len(node):
            node = node[int(key)]
            continue
        if isinstance(node, list) and "=" in key:  # the list's object with that value: points.value=light_c
            col, want = key.split("=", 1)
            while keys and not any(isinstance(d, dict) and col in d and _matches(d[col], "=", want) for d in node):
                want += "." + keys.pop(0)  # a value with dots: value=0.5
            found = [d for d in node if isinstance(d, dict) and col in d and _matches(d[col], "=", want)]
            if len(found) != 1:
                raise ResultError(f"{len(found)} objects with {col} = {want} on the path {sel!r}")
            node = found[0]
            continue
        while isinstance(node, dict) and key not in node and keys:  # a key with dots: AWGN(sigma=0.025)
            key += "." + keys.pop(0)
        if not (isinstance(node, dict) and key in node):
            raise ResultError(f"no key {key!r} on the path {sel!r}")
        node = node[key]
    if not isinstance(node, dict):
        raise ResultError(f"{sel!r} is not an object: select the object, name its key after it")
    return [node]


def _value(row: dict, name: str):
    if name not in row:
        raise ResultError(f"no column or key {name!r} (there are: {', '.join(map(str, row))})")
    return row[name]


def _eval(node, rows: list[dict]):
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _AGG:
        if not node.args or node.keywords:
            raise ResultError(f"{node.func.id}() takes expressions")
        if len(node.args) > 1:  # over its arguments, in one row: max(a, b)
            return _AGG[node.func.id]([_arith(_eval(a, rows)) for a in node.args])
        return _AGG[node.func.id]([_arith(_eval(node.args[0], [r])) for r in rows])
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "abs" and not node.keywords:
        return abs(_arith(_eval(node.args[0], rows)))
    if len(rows) != 1:
        raise ResultError(f"{len(rows)} rows match: narrow the selector, or take min(), max() or mean()")
    if isinstance(node, ast.Name):
        return _value(rows[0], node.id)
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _arith(_eval(node.operand, rows))
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.BinOp) and type(node.op) in _BIN:
        return _BIN[type(node.op)](_arith(_eval(node.left, rows)), _arith(_eval(node.right, rows)))
    raise ResultError(f"{ast.unparse(node)!r}: only columns, numbers, + − × / ** and abs/min/max/mean")


def _arith(v) -> float:
    x = v if isinstance(v, (int, float)) and not isinstance(v, bool) else _number(v)
    if x is None:
        raise ResultError(f"{v!r} is not a number")
    return float(x)


def format_number(x, fmt: str | None = None) -> str:
    """`x` with `fmt` in the documentation's notation: 1.1e-5 (no exponent padding), − for minus, ∞. Without a
    format: a whole number as it is (31), any other with 3 significant digits."""
    if fmt == "dagger":  # a note column: † where the note is there (an end that is not a confidence limit)
        return "†" if str(x).strip() else ""
    if isinstance(x, bool) or str(x) in ("True", "False"):
        return "yes" if str(x) == "True" else "no"
    if isinstance(x, str) and _number(x) is None:
        return x.split(":")[0] if fmt == "head" else x
    x = _arith(x)
    if fmt is None:
        fmt = "d" if x.is_integer() and abs(x) < 1e6 else ".3s"
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    if math.isnan(x):
        raise ResultError("the value is NaN")
    if fmt == "time":  # seconds as a duration: 40.6 s, 14 min 22 s, 2 h 5 min
        m, sec = divmod(round(x), 60)
        return f"{x:.3g} s" if x < 100 else f"{m} min {sec} s" if m < 60 else f"{m // 60} h {m % 60} min"
    sig = re.fullmatch(r"\.(\d+)s", fmt)
    if sig:  # n significant digits, trailing zeros kept; plain from 1e-4 to 1e5, else an exponent
        n = max(int(sig[1]), 1)
        x = float(f"{x:.{n - 1}e}")
        e = math.floor(math.log10(abs(x))) if x else 0
        text = "0" if x == 0 else f"{x:.{max(n - 1 - e, 0)}f}" if -4 <= e < 5 else f"{x:.{n - 1}e}"
    elif fmt == "d":
        text = str(round(x))
    else:
        text = format(x, fmt)
    text = re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m[1] == "-" else "") + m[2], text)
    return "−" + text[1:] if text.startswith("-") else text


def resolve(spec: str, root: Path = RESULTS) -> str:
    """The text a `{result}` role with `spec` prints, read from the files under `root` (default: results/).

    Raises ResultError when the spec is malformed or names a file, row, column or key that is not there.
    """
    m = _SPEC.match(spec)
    if not m:
        raise ResultError(f"{spec!r}: write FILE[SELECTOR] EXPRESSION :FORMAT")
    path = (root / m["file"]).resolve()
    if not path.is_file():
        raise ResultError(f"{m['file']}: no such file under {root.name}/")
    try:
        tree = ast.parse(m["expr"], mode="eval").body
    except SyntaxError as e:
        raise ResultError(f"{m['expr']!r}: not an expression ({e.msg})") from None
    try:
        rows = _rows(_load(path, (path.stat().st_mtime_ns, path.stat().st_size)), m["sel"])
        value = _eval(tree, rows)
        return format_number(value, m["fmt"] or None)
    except ResultError as e:
        raise ResultError(f"{m['file']}: {e}") from None
    except (ValueError, ZeroDivisionError, OverflowError) as e:
        raise ResultError(f"{m['file']}: {m['expr']!r}: {e}") from None


def result_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    from docutils import nodes

    try:
        return [nodes.Text(resolve(text))], []
    except ResultError as e:
        msg = inliner.reporter.error(f"{{result}}`{text}`: {e}", line=lineno)
        return [inliner.problematic(rawtext, rawtext, msg)], [msg]


def setup(app):
    app.add_role("result", result_role)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
