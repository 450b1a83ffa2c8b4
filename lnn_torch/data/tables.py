"""Recorded tables read as numbers: one CSV (or TSV, TXT, DAT, gzip-compressed or not) per recording,
its named columns as float64 with one line naming the file, line and column of any bad cell (the
format: ``lnn_torch.data.importer``)."""

from __future__ import annotations

import csv
import itertools
import math
from pathlib import Path

import numpy as np

from ..errors import InputError

DECIMALS = ("auto", ".", ",")
EXTENSIONS = (".csv", ".tsv", ".txt", ".dat")  # removed (after .gz) from a file's name to name its recording


def recording_name(path: str | Path) -> str:
    """A recording's name: its file's name without ``.gz``, then without ``.csv``, ``.tsv``, ``.txt`` or
    ``.dat`` (``run.csv.gz`` and ``run.csv``: ``run``; ``exp_2024.05.01_a.csv``: ``exp_2024.05.01_a``)."""
    name = Path(path).name
    if name.lower().endswith(".gz") and len(name) > 3:
        name = name[:-3]
    ext = next((e for e in EXTENSIONS if name.lower().endswith(e)), None)
    return name[:-len(ext)] if ext is not None and len(name) > len(ext) else name


WHITESPACE = "whitespace"  # the delimiter setting of columns separated by runs of spaces and tabs


def separator(delimiter: str | None) -> str | None:
    """A ``delimiter`` setting as the character it is (``tab``: a tab; ``whitespace`` as it is: any run of spaces
    and tabs, as column-aligned ``.dat`` files have; None: detected per file), or None if it cannot be one."""
    if delimiter == WHITESPACE:
        return WHITESPACE
    sep = "\t" if delimiter in ("tab", "\\t") else delimiter
    return sep if isinstance(sep, str) and len(sep) == 1 and sep not in "\"#\r\n" else None


def _shown(sep: str) -> str:
    return "tab" if sep == "\t" else sep if sep == WHITESPACE else repr(sep)


def read_csv_columns(path: Path, columns: list[str], delimiter: str | None = None, decimal: str = "auto") -> np.ndarray:
    """The named columns of a CSV file (``.csv``, or gzip-compressed ``.csv.gz``; lines starting
    with ``#`` are comments, before the header or between rows) as float64 ``(rows, len(columns))``;
    errors name the file and line (``read_csv_table`` says which; ``delimiter``, ``decimal``: as
    ``ImportSpec``'s)."""
    return read_csv_table(path, columns, delimiter, decimal)[0]




def read_csv_table(path: Path, columns: list[str], delimiter: str | None = None,
                   decimal: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """``(values (rows, len(columns)) float64, lines (rows,) int64)``: the named columns of a CSV file
    and the line of the file each data row ends on. The delimiter is ``delimiter`` (one character or
    ``tab``), or else the header's: ``;`` if it holds one, else a tab if it holds one, else ``,``;
    ``decimal`` (``auto``, ``.``, ``,``): ``auto`` reads decimal commas where the delimiter is not ``,``;
    ``whitespace``: columns separated by runs of spaces and tabs (no quoting).
    Text is UTF-8 (a byte-order mark is dropped), gzip-compressed where the name ends in ``.gz``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    import gzip

    if path.is_dir():
        raise InputError(f"{path}: a folder, not a recording (give its files, e.g. {path}/*.csv)")
    with open(path, "rb") as fh:  # gzip by its magic bytes, whatever the name says (.GZ, a .csv that is one)
        compressed = fh.read(2) == b"\x1f\x8b"
    opener = gzip.open if compressed or path.suffix.lower() == ".gz" else open
    try:
        return _parse_csv(path, opener, columns, delimiter, decimal)
    except EOFError:
        raise InputError(f"{path}: truncated (the compressed file ends early)") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: {_undecodable(path, opener)}") from None
    except csv.Error as err:
        raise InputError(f"{path}: not a readable CSV file ({err})") from None
    except OSError as err:  # gzip.BadGzipFile, ...
        raise InputError(f"{path}: cannot read it ({err})") from None


class _Whitespace:
    """Rows of a file whose columns are separated by runs of spaces or tabs (no quoting), read as ``csv.reader``
    reads a delimited one (``line_num``: the lines read so far)."""

    def __init__(self, lines) -> None:
        self.lines, self.line_num = iter(lines), 0

    def __iter__(self):
        return self

    def __next__(self) -> list[str]:
        line = next(self.lines)
        self.line_num += 1
        return [cell.strip('"') for cell in line.split()]  # (a quoted name of one word: "time")


def _undecodable(path: Path, opener) -> str:
    """Where a file stops being UTF-8 text: its first such line, and the way out."""
    with opener(path, "rb") as fh:
        if fh.read(2) in (b"\xff\xfe", b"\xfe\xff"):
            return "UTF-16 text (its byte-order mark): save it as UTF-8"
        fh.seek(0)
        for n, raw in enumerate(fh, start=1):
            try:
                raw.decode("utf-8")
            except UnicodeDecodeError as err:
                byte = raw[err.start:err.start + 1].hex()
                return (f"line {n}: byte 0x{byte} is not UTF-8 text (a file saved as Latin-1 or Windows-1252, where a "
                        "degree sign or an accent is one byte?): save it as UTF-8")
    return "not a text CSV file (undecodable bytes)"


def _number(cell: str) -> float:
    """A cell as a CSV writes a number: what Python's float reads but for digit-group underscores (``1_000``) and
    other scripts' digits and spaces, which no logger writes for a number (they were read as 1000 and 12)."""
    value = float(cell)
    core = cell.strip()  # (any space around it, a no-break space too)
    if "_" in core or not core.isascii():
        raise ValueError(cell)
    return value


def _parse_csv(path: Path, opener, columns: list[str], delimiter: str | None,
               decimal: str) -> tuple[np.ndarray, np.ndarray]:
    with opener(path, "rt", encoding="utf-8-sig", newline="") as fh:
        before = 0  # comment and blank lines before the header
        for header_line in fh:
            if header_line.strip() and not header_line.lstrip().startswith("#"):
                break
            before += 1
        else:
            raise InputError(f"{path}: the file is empty" if not before else
                             f"{path}: no header row (only comment or blank lines)")
        bare = "".join(header_line.split('"')[::2])  # (a delimiter inside a quoted name is no delimiter)
        sep = separator(delimiter) if delimiter is not None else (
            ";" if ";" in bare else "\t" if "\t" in bare else ",")
        if sep is None:
            raise InputError(f"{path}: delimiter must be one character (or 'tab' or 'whitespace'), got {delimiter!r}")
        if decimal not in DECIMALS:
            raise InputError(f"{path}: decimal must be one of {', '.join(DECIMALS)}, got {decimal!r}")
        if decimal == "," and sep == ",":
            raise InputError(f"{path}: decimal ',' needs a delimiter other than ',' (the header is read with ',')")
        commas = decimal == "," or (decimal == "auto" and sep != ",")
        lines_in = itertools.chain([header_line], fh)
        reader = _Whitespace(lines_in) if sep == WHITESPACE else csv.reader(lines_in, delimiter=sep)
        header = [h.strip() for h in next(reader)]
        at = before + 1
        missing = [c for c in dict.fromkeys(columns) if c not in header]
        if missing:
            hint = "; set delimiter if the file uses another" if len(header) == 1 else ""
            raise InputError(f"{path}: no column {', '.join(repr(c) for c in missing)} in the header on line {at} "
                             f"(delimiter {_shown(sep)}; columns: {', '.join(header)}){hint}")
        twice = [c for c in dict.fromkeys(columns) if header.count(c) > 1]
        if twice:
            raise InputError(f"{path}: line {at}: the header names column {twice[0]!r} {header.count(twice[0])} times "
                             "(which one is meant?): rename the others")
        index = [header.index(c) for c in columns]
        rows, lines = [], []
        marks: dict[str, tuple] = {}  # (decimal commas) the first cell written with each mark: "." and ","
        for row in reader:
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue  # (a blank line, or a comment line: a logger's marker between rows)
            line = before + reader.line_num  # the file's line (the row's last, if a quoted cell spans lines)
            if len(row) > len(header) and any(cell.strip() for cell in row[len(header):]):
                raise InputError(f"{path}: line {line}: {len(row)} cells, the header names {len(header)} (two rows "
                                 "run together, or a delimiter inside a value?)")
            try:
                values = [_number(row[i].replace(",", ".")) if commas else _number(row[i]) for i in index]
            except (ValueError, IndexError):
                raise InputError(_cell_error(path, line, row, header, columns, index, commas)) from None
            if commas and len(marks) < 2:
                _decimal_marks(marks, path, line, row, columns, index, decimal)
            bad = [c for c, v in zip(columns, values, strict=True) if not math.isfinite(v)]
            if bad:
                raise InputError(f"{path}: line {line}: NaN or Inf in column {bad[0]!r}")
            rows.append(values)
            lines.append(line)
    if len(rows) < 2:
        raise InputError(f"{path}: fewer than two data rows")
    return np.asarray(rows, dtype=np.float64), np.asarray(lines, dtype=np.int64)


def _decimal_marks(marks: dict, path: Path, line: int, row: list[str], columns: list[str], index: list[int],
                   decimal: str) -> None:
    """Where commas are decimal marks, a number written with a point (``1.500``: 1.5, or a thousands separator
    for 1500?) is refused when decimal ',' is set, or when the file writes another with a comma (``auto``)."""
    for c, i in zip(columns, index, strict=True):
        cell = row[i].strip()
        for mark in ".,":
            if mark in cell and mark not in marks:
                marks[mark] = (line, c, cell)
    if "." in marks and (decimal == "," or "," in marks):
        at, c, cell = marks["."]
        other = (f"where line {marks[','][0]} writes {marks[','][2]!r} in column {marks[','][1]!r} with a decimal "
                 "comma" if "," in marks else "with decimal ','")
        raise InputError(f"{path}: line {at}: column {c!r}: {cell!r} has a point {other} (a thousands separator? "
                         "write every number with one decimal mark, or set decimal)")


def _cell_error(path: Path, line: int, row: list[str], header: list[str], columns: list[str], index: list[int],
                commas: bool) -> str:
    """The one line that names the first cell of ``row`` (of the named ``columns``) that is not a number."""
    for c, i in zip(columns, index, strict=True):
        if i >= len(row):
            return (f"{path}: line {line}: no value in column {c!r} (the row has {len(row)} cells, the header "
                    f"{len(header)})")
        cell = row[i].strip()
        try:
            _number(cell.replace(",", ".") if commas else cell)
        except ValueError:
            if not cell:
                return f"{path}: line {line}: column {c!r} is empty"
            if "\n" in cell:  # a quote that opened and never closed swallowed the lines after it
                first = line - cell.count("\n")
                return (f"{path}: line {first}: a quoted cell in column {c!r} runs on for {cell.count(chr(10))} lines "
                        "(a quote that is never closed?)")
            if len(cell) > 40:
                cell = cell[:37] + "..."
            hint = (" (decimal commas are read with decimal ',' or 'auto' and a delimiter other than ',')"
                    if "," in cell and not commas else "")
            return f"{path}: line {line}: column {c!r}: {cell!r} is not a number{hint}"
    return f"{path}: line {line}: a value of {', '.join(columns)} is missing or not a number"
