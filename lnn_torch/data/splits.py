"""The entries and splits of an imported dataset: recordings named per split, seeded fractions, or
time windows inside recordings (``"run[0.5:10.5]"``) that may not overlap across splits."""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError, is_number

WINDOW = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<start>[^:\]]*):(?P<end>[^\]]*)\]$")


def split_entries(names: list[str], split, seed: int, durations: list[float]) -> tuple[list[tuple], dict]:
    """The dataset's entries ``(recording index, start s or None, end s or None, name)`` and the split
    over them: whole recordings (named, or seeded fractions), or time windows ``name[start:end]``."""
    split = _split_form(split)
    if not isinstance(split, dict) or not any(WINDOW.match(str(item).strip()) for items in split.values()
                                              for item in (items or [])):
        entries = [(i, None, None, n) for i, n in enumerate(names)]  # every recording, in the files' order
        return entries, _by_name(names, split) if isinstance(split, dict) else _fractions(names, split, seed)
    entries, out = [], {}
    for part in ("train", "val", "test"):
        out[part] = []
        for item in split.get(part, []) or []:
            m = WINDOW.match(str(item).strip())
            name = m["name"].strip() if m else str(item)
            if name not in names:
                raise InputError(f"split: unknown recording {name!r} (recordings: {', '.join(names)})")
            i = names.index(name)
            start = end = None
            if m:
                try:
                    start = float(m["start"]) if m["start"].strip() else None
                    end = float(m["end"]) if m["end"].strip() else None
                except ValueError:
                    raise InputError(f"split: window {item!r}: start and end must be seconds") from None
                if not all(x is None or np.isfinite(x) for x in (start, end)) or (start is not None and start < 0):
                    raise InputError(f"split: window {item!r}: start and end must be finite seconds from the "
                                     "recording's first sample, the start >= 0")
                if start is not None and end is not None and end <= start:
                    raise InputError(f"split: window {item!r} ends before it starts")
                # (a window past the recording's end was cut to it without a word; one per cent of it is slack: an
                # end written as the recording's nominal length, a sample or two past its last)
                last = durations[i] * 1.01 + 1e-9
                if (start or 0.0) < durations[i] and end is not None and end > last:  # (a start past the end:
                    # _pieces says it holds no sample, and where windows count from)
                    raise InputError(f"split: window {item!r} reaches beyond the recording {name!r}, which is "
                                     f"{durations[i]:.6g} s long (leave the end out for the rest of it: "
                                     f"{name}[{m['start'].strip()}:])")
            entry = (i, start, end, str(item).strip() if m else name)
            if entry in entries:
                raise InputError(f"split: {entry[3]!r} is named twice")
            out[part].append(len(entries))
            entries.append(entry)
    if not any(out.values()):
        raise InputError("split: no recording in any split")
    for a in range(len(entries)):  # entries of different splits may not share any time of a recording
        for b in range(a + 1, len(entries)):
            (i, s0, e0, n0), (j, s1, e1, n1) = entries[a], entries[b]
            part_a = next(p for p, idx in out.items() if a in idx)
            part_b = next(p for p, idx in out.items() if b in idx)
            lo0, hi0 = s0 or 0.0, durations[i] if e0 is None else e0
            lo1, hi1 = s1 or 0.0, durations[j] if e1 is None else e1
            if i == j and part_a != part_b and lo0 < hi1 and lo1 < hi0:
                raise InputError(f"split: {n0!r} ({part_a}) and {n1!r} ({part_b}) overlap: a held-out window must "
                                 "not share samples with training")
    return entries, {k: np.asarray(v, dtype=np.int64) for k, v in out.items()}


def _by_name(names: list[str], split: dict) -> dict:
    known = set(names)
    out = {}
    for part in ("train", "val", "test"):
        chosen = list(split.get(part, []) or [])
        unknown = [n for n in chosen if n not in known]
        if unknown:
            raise InputError(f"split: unknown recording(s) {', '.join(unknown)} (recordings: {', '.join(names)})")
        out[part] = np.array(sorted(names.index(n) for n in chosen), dtype=np.int64)
    used = np.concatenate(list(out.values()))
    if len(np.unique(used)) != len(used):
        values, counts = np.unique(used, return_counts=True)
        twice = [names[int(i)] for i in values[counts > 1]]
        where = {n: [part for part in out if names.index(n) in out[part]] for n in twice}
        raise InputError("split: a recording is named in more than one split: "
                         + "; ".join(f"{n} ({' and '.join(parts) if len(parts) > 1 else 'twice in ' + parts[0]})"
                                     for n, parts in where.items()))
    if not any(len(v) for v in out.values()):
        raise InputError("split: no recording in any split")
    return out


def _split_form(split):
    """``split`` as ``_entries`` reads it: a dict of fractions (``{train: 0.7, val: 0.15, test: 0.15}``)
    becomes the list of three; a dict's values must be lists (or one name); anything else is refused."""
    if not isinstance(split, dict):
        return split
    unknown = sorted(set(split) - {"train", "val", "test"})
    if unknown:
        raise InputError(f"split: unknown part(s) {', '.join(map(repr, unknown))} (train, val, test)")
    if split and all(is_number(v) for v in split.values()):
        return [float(split.get(part, 0.0)) for part in ("train", "val", "test")]
    out = {}
    for part, items in split.items():
        if isinstance(items, str):
            items = [items]
        if items is not None and not isinstance(items, (list, tuple)):
            raise InputError(f"split: {part} must be a list of recording names or windows (or every part a "
                             f"fraction), got {items!r}")
        out[part] = items
    return out


def _fractions(names: list[str], split, seed: int) -> dict:
    usage = ("split must be three fractions summing to 1 ([0.7, 0.15, 0.15]) or the recordings (or windows) of "
             "each part ({train: [...], val: [...], test: [...]})")
    if not isinstance(split, (list, tuple)) or not all(is_number(x, finite=True) for x in split):
        raise InputError(f"{usage}, got {split!r}")
    fractions = [float(x) for x in split]
    if len(fractions) != 3 or any(f < 0 for f in fractions) or abs(sum(fractions) - 1) > 1e-9:
        raise InputError(f"{usage}, got {split!r}")
    n = len(names)
    perm = np.random.default_rng(np.random.SeedSequence(int(seed))).permutation(n)
    n_val, n_test = int(round(fractions[1] * n)), int(round(fractions[2] * n))
    n_train = n - n_val - n_test
    if n_train < 1:
        raise InputError(f"split: {n} recordings leave none for training with fractions {fractions}")
    return {"train": np.sort(perm[:n_train]), "val": np.sort(perm[n_train:n_train + n_val]),
            "test": np.sort(perm[n_train + n_val:])}
