"""A stack's written sun-bounce images read back as the client decodes them, in one pass
(docs/sun.md, "Shared images"): each image against the column it was made of (the errors the
budget is about), each sun-path patch's own gain on its group's image
(:func:`bake.sunshare.least_squares_gain`), and each patch against its own column as
displayed (what sharing costs). Each image file is decoded once and each master column read
once, in batches of whole groups; before 2026-12-07 three passes each decoded every image
and read every column again (a stack on disk reads its block files whole for every read:
bake.rowstore.StackStore.columns).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bake.compact_reader import CompactReader
from bake.ktx2decoder import decode
from bake.rowstore import as_stack
from bake.sundisplay import DisplayCheck, max_median
from bake.sunshare import (
    SharedColumns,
    SharedImages,
    group_batches,
    least_squares_gain,
    scaled_levels,
)


class DecodedOnce:
    """:func:`bake.ktx2decoder.decode` for a :class:`CompactReader`, each file decoded once
    and kept until :meth:`forget` (the decoder is deterministic: the same arrays)."""

    def __init__(self):
        self.files: dict[Path, np.ndarray] = {}

    def __call__(self, files: list[Path]) -> list[np.ndarray]:
        missing = [f for f in dict.fromkeys(files) if f not in self.files]
        self.files.update(zip(missing, decode(missing), strict=True))
        return [self.files[f] for f in files]

    def forget(self) -> None:
        self.files.clear()


@dataclass
class ReadBack:
    """What :func:`read_back` measured. For each light of the images' ``lights``, in their
    order: ``rms`` its decoded image against the column it was made of, RMS over the valid
    texels over the column's mean there; ``displayed`` and ``texel`` the same as displayed
    (:meth:`DisplayCheck.error`, :meth:`DisplayCheck.texel_error`; empty without a check).
    With shared images: ``gains`` (lowest, highest) over the members' gains and channels;
    ``own_displayed``/``own_texel`` {member: its error against its own column}."""

    rms: np.ndarray
    displayed: np.ndarray
    texel: np.ndarray
    gains: tuple[float, float] | None = None
    own_displayed: dict = field(default_factory=dict)
    own_texel: dict = field(default_factory=dict)

    def shared_record(self, lights: list[int], budget: float | None) -> dict:
        """``error.displayed.shared`` of the manifest: each of ``lights`` (the check's, in
        its order) against its own column as displayed: ``{"max", "median",
        "worst_light", "lights", "texel_p99", "over_budget"}`` (the last with a budget)."""
        displayed = np.array([self.own_displayed[p] for p in lights])
        texel = np.array([self.own_texel[p] for p in lights])
        out = {"max": round(float(displayed.max()), 6),
               "median": round(float(np.median(displayed)), 6),
               "worst_light": int(lights[int(np.argmax(displayed))]),
               "lights": len(lights),
               "texel_p99": max_median(texel)}
        if budget is not None:
            out["over_budget"] = int((displayed > budget).sum())
        return out


def column_error(decoded: np.ndarray, column: np.ndarray, valid: np.ndarray) -> float:
    """RMS of ``decoded - column`` (both (H, W, 3)) over the ``valid`` texels (H, W), over
    the column's mean there."""
    truth = column[valid].astype(np.float64)
    rms = np.sqrt(((decoded[valid] - truth) ** 2).mean())
    return float(rms / max(float(truth.mean()), 1e-30))


def read_back(out_dir: Path, entry: dict, own, lights, check: DisplayCheck | None,
              shared: SharedImages | None = None) -> ReadBack:
    """Read a sun-bounce stack's written images back as the client decodes them
    (:class:`CompactReader` of ``entry``, whose files are in ``out_dir``) and judge them:
    each image of ``lights`` against the column it was made of (its own column of ``own``,
    (H, W, n, 3); with ``shared``, its group's: :class:`SharedColumns`), and by ``check``
    as displayed.

    With ``shared`` (``entry`` after :func:`bake.sunshare.share_entry`), every member ``p``
    of every group of ``lights`` is also given its own gain per channel, the least-squares
    one of its decoded image against its own column over the valid texels (``entry``'s
    ``scale[p]`` and ``offset[p]``, every level, multiplied by it), and is then judged
    against its own column by ``check`` (docs/sun.md, "Each patch's own gain, and sharing
    only within the budget"). A representative's own error is measured before its gain
    (against its group's column: its image's encoding error).

    Why a gain: the group's image is its members' mean, and part of how a member's own
    bounce differs from it is strength (the sun's cosine on the surfaces that throw it off
    changes across a group, up to twice from the lowest row of patches to the next), which
    the gain restores; the rest is pattern, which :func:`bake.sunshare.groups_within` judges.
    As displayed, the relit sky and the sun's direct term do not depend on the gain, so the
    least-squares one is the gain with the smallest error the judge can see for that
    image."""
    own = as_stack(own)
    valid = own.valid
    lights = [int(i) for i in lights]
    groups = {p: (shared.groups.get(p, [p]) if shared is not None else [p]) for p in lights}
    grouped = SharedColumns(own, shared) if shared is not None else None
    decoder = DecodedOnce()
    reader = CompactReader(out_dir, entry, own.shape[:2], decoder=decoder)
    table = entry["lights"]
    rms, displayed, texel = {}, {}, {}  # {light: ...} of the images' lights
    own_displayed, own_texel = {}, {}  # {member: ...} against its own column
    lowest, highest = np.inf, -np.inf
    for batch in group_batches(lights, groups):
        members = [q for p in batch for q in groups[p]]
        columns = dict(zip(members, own.columns(members), strict=True))
        shown = (dict(zip(members, check.shown_but_bounce(members), strict=True))
                 if check is not None else None)
        decoded = reader.lights(members)  # unshared, the members are the batch
        for p in batch:
            made_of = (columns[p] if grouped is None
                       else grouped.group_column(p, groups[p], columns))
            rms[p] = column_error(decoded[p], made_of, valid)
            if check is not None:
                displayed[p], texel[p] = check.errors(p, shown[p], made_of, decoded[p])
        if shared is not None:
            for q in members:
                gain = least_squares_gain(decoded[q][valid], columns[q][valid])
                table["scale"][q] = scaled_levels(table["scale"][q], gain)
                table["offset"][q] = scaled_levels(table["offset"][q], gain)
                lowest, highest = min(lowest, gain.min()), max(highest, gain.max())
            if check is not None:
                reader.forget_lights()  # drawn again with the gains
                regained = reader.lights(members)
                for q in members:
                    own_displayed[q], own_texel[q] = check.errors(
                        q, shown[q], columns[q], regained[q])
        reader.forget_lights()
        decoder.forget()
    return ReadBack(
        rms=np.array([rms[p] for p in lights]),
        displayed=np.array([displayed[p] for p in lights if p in displayed]),
        texel=np.array([texel[p] for p in lights if p in texel]),
        gains=(round(float(lowest), 4), round(float(highest), 4)) if shared is not None
        else None,
        own_displayed=own_displayed, own_texel=own_texel,
    )
