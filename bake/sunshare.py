"""Neighbouring sun-path patches sharing one sun-bounce image (docs/sun.md, "Shared
images"): which patches share (:class:`SharedImages`, grouped by a coarser dome's patches),
the columns their images are made of (:class:`SharedColumns`), the patches taken out of
their groups where sharing would show (:func:`groups_within`), each member's own gain
(:func:`fit_member_gains`) and what sharing costs each patch as displayed
(:func:`shared_errors`). bake.sunbounce encodes the images; bake.sundisplay judges them.
Moved out of bake/sunbounce.py on 2026-12-07 (the module had grown past 500 lines).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bake.compact_reader import CompactReader
from bake.quantize import float32_list
from bake.rowstore import as_stack
from bake.sundisplay import (
    SUN_BOUNCE_DECODE_CHUNK,
    TEXEL_BOUND_PER_BUDGET,
    DisplayCheck,
    max_median,
    sun_bounce_errors,
)

# Of the budget as displayed, the share a patch's sharing of its group's image may take
# before encoding (groups_within); the image's encoding error, judged against the group's
# column, takes the rest (errors of both kinds add about in quadrature: 0.7^2 + 0.7^2 ~ 1).
SHARING_SHARE = 0.7


@dataclass
class SharedImages:
    """Which sun-path lights share one sun-bounce image: ``groups`` {representative light:
    its members, sorted, the representative first}. A group is the sun-path patches whose
    centroids lie in one patch of a coarser dome (:meth:`of_dome`); its
    image is its members' columns summed and scaled to the representative's solid angle,
    ``omega_rep / sum(omega_q) * sum_q B_q``, so that with the sun in any member ``p`` the
    client's ``E_sun / omega_p * column_p`` (``column_p``: the shared image scaled by
    ``omega_p / omega_rep``) is ``E_sun * sum_q B_q / sum_q omega_q``: the sun's bounce
    averaged over the group's patches; each member then scales it by its own least-squares
    gain per channel (:func:`fit_member_gains`)."""

    groups: dict[int, list[int]]
    solid_angles_sr: np.ndarray  # (n,) the dome's
    kind: str
    frequency: int  # the coarser dome's

    @classmethod
    def of_dome(cls, kind: str, frequency: int, lights, max_lights: int | None
                ) -> SharedImages | None:
        """The groups of ``lights`` (the sun-path patches) of a ``kind`` dome of this
        ``frequency`` by the patches of the dome of about ``max_lights`` lights
        (:meth:`bake.dome.Dome.for_light_count`), or None when the build's dome has no more
        lights than that (or ``max_lights`` is None): the sun's bounce is kept at no finer an
        angular step than that dome's."""
        from bake.dome import Dome
        from daylit.spherical import PatchLookup

        fine = Dome.build(kind, frequency)
        if not max_lights or fine.count <= max_lights:
            return None
        rough = Dome.for_light_count(max_lights)
        if rough.count >= fine.count:
            return None
        owner = PatchLookup(rough.vertices)(fine.centroids)
        by_patch: dict[int, list[int]] = {}
        for p in sorted(int(i) for i in lights):
            key = int(owner[p]) if owner[p] >= 0 else -1 - p  # outside every coarse patch: alone
            by_patch.setdefault(key, []).append(p)
        groups = {members[0]: members for members in by_patch.values()}
        return cls(groups, fine.solid_angles_sr, rough.kind, rough.frequency)

    @property
    def representatives(self) -> list[int]:
        return sorted(self.groups)

    def image_of(self, n: int) -> list:
        """(n,) the light whose files hold each light's image; None for lights without."""
        out: list = [None] * n
        for rep, members in self.groups.items():
            for q in members:
                out[q] = rep
        return out

    def ratio(self, light: int, rep: int) -> float:
        """``omega_light / omega_rep``: a member's scale and offset over its image's."""
        return float(self.solid_angles_sr[light] / self.solid_angles_sr[rep])


class SharedColumns:
    """A sun-bounce stack (a :mod:`bake.rowstore` stack) read as :class:`SharedImages` store
    it: a representative's column is its group's, ``omega_rep / sum(omega_q) * sum_q B_q``;
    any other light's its own."""

    def __init__(self, image, shared: SharedImages):
        self.image = as_stack(image)
        self.shared = shared
        self.shape = self.image.shape
        self.valid = self.image.valid
        self.work = getattr(self.image, "work", None)

    def columns(self, lights) -> np.ndarray:
        out = []
        omega = self.shared.solid_angles_sr
        for p in lights:
            members = self.shared.groups.get(int(p), [int(p)])
            total = np.zeros(self.shape[:2] + (3,), dtype=np.float64)
            for column in self.image.columns(members):
                total += column
            out.append((total * (omega[p] / omega[members].sum())).astype(np.float32))
        return np.stack(out)

    def column(self, light: int) -> np.ndarray:
        return self.columns([light])[0]


def share_entry(entry: dict, shared: SharedImages, n: int) -> dict:
    """A sun-bounce entry whose ``lights`` hold the representatives' images, extended to
    every member: ``scale``/``offset`` the representative's times ``omega_p / omega_rep``,
    ``image[p]`` the representative (whose files hold the image), and ``shared``: the
    coarser dome and how many images."""
    table = entry["lights"]
    for rep, members in shared.groups.items():
        for q in members:
            if q == rep:
                continue
            f = shared.ratio(q, rep)
            table["scale"][q] = [float32_list(np.asarray(level) * f)
                                 for level in table["scale"][rep]]
            table["offset"][q] = [float32_list(np.asarray(level) * f)
                                  for level in table["offset"][rep]]
    table["image"] = shared.image_of(n)
    entry["shared"] = {"kind": shared.kind, "frequency": shared.frequency,
                       "images": len(shared.groups),
                       "lights": sum(len(m) for m in shared.groups.values())}
    return entry


def groups_within(shared: SharedImages, own, check: DisplayCheck, budget: float
                  ) -> SharedImages:
    """``shared`` with the patches that sharing would put over :data:`SHARING_SHARE` of
    ``budget`` as displayed taken out of their groups, each to an image of its own: in each
    group, the group's column (the members' solid-angle mean) times each member's
    least-squares gain (:func:`least_squares_gain`, as :func:`fit_member_gains` will give
    it) is judged against the member's own column of ``own`` (H, W, n, 3) by ``check`` (made
    with ``bounce=own``, holding every member), by its RMS (:meth:`DisplayCheck.error`) and at
    single texels (:meth:`DisplayCheck.texel_error`, against :data:`TEXEL_BOUND_PER_BUDGET`
    times the budget); while the worst member is over either, it leaves the group and the
    rest's mean is judged again. Before encoding: the rest of the budget is the image's
    encoding's."""
    own = as_stack(own)
    valid = own.valid
    omega = shared.solid_angles_sr
    limit = SHARING_SHARE * budget
    texel_limit = SHARING_SHARE * TEXEL_BOUND_PER_BUDGET * budget
    # Whole groups, about SUN_BOUNCE_DECODE_CHUNK lights at a time: a stack on disk reads
    # every row of a block of lights for each call (bake.rowstore.StackStore.columns).
    batches: list[list[list[int]]] = [[]]
    for members in shared.groups.values():
        if batches[-1] and sum(map(len, batches[-1])) + len(members) > SUN_BOUNCE_DECODE_CHUNK:
            batches.append([])
        batches[-1].append(list(members))
    groups: dict[int, list[int]] = {}
    for batch in batches:
        lights = [p for members in batch for p in members]
        columns = dict(zip(lights, own.columns(lights), strict=True))
        shown = dict(zip(lights, check.shown_but_bounce(lights), strict=True))
        for members in batch:
            while len(members) > 1:
                total = (sum(columns[q].astype(np.float64) for q in members)
                         / omega[members].sum())
                over = []  # each member's error over its limit, the larger of the two
                for p in members:
                    mean = total * omega[p]
                    shared_p = mean * least_squares_gain(mean[valid], columns[p][valid])
                    rms, p99 = check.errors(p, shown[p], columns[p], shared_p)
                    over.append(max(rms / limit, p99 / texel_limit))
                worst = int(np.argmax(over))
                if over[worst] <= 1.0:
                    break
                alone = members.pop(worst)
                groups[alone] = [alone]
            groups[members[0]] = members
    return SharedImages(dict(sorted(groups.items())), omega, shared.kind, shared.frequency)


def codec_texel_bounds(lights, budget: float, shared: SharedImages | None) -> dict[int, float]:
    """{light: the error at single texels a codec cheaper than plain UASTC may make in its
    image} (:data:`TEXEL_BOUND_PER_BUDGET` times ``budget``): an image that a group shares
    gets what sharing left of the bound, ``1 - SHARING_SHARE`` of it (a member's error
    against its own column is the sharing's and the codec's; at single texels they add, as
    the tests' sun site showed: 4.2 % with the whole bound for each)."""
    bounds = {int(i): TEXEL_BOUND_PER_BUDGET * budget for i in lights}
    for rep, members in (shared.groups.items() if shared is not None else ()):
        if len(members) > 1 and rep in bounds:
            bounds[rep] *= 1.0 - SHARING_SHARE
    return bounds


def fit_member_gains(out_dir: Path, entry: dict, own, lights) -> None:
    """Give each light ``p`` of ``lights`` that reads a shared image (``entry`` after
    :func:`share_entry`) its own gain per channel: the least-squares one, over the valid
    texels of ``own`` (H, W, n, 3, each patch's own column), of its decoded image against its
    own master column, ``g_c = sum(decoded_c * own_c) / sum(decoded_c ** 2)``; its ``scale``
    and ``offset`` (every level) are multiplied by it, so the client draws ``g`` times the
    group's image with no change of its own.

    The group's image is the members' mean; part of how a member's own bounce differs from it
    is strength (the sun's cosine on the surfaces that throw it off changes across a group, up
    to twice from the lowest row of patches to the next), which the gain restores; the rest is
    pattern, which :func:`groups_within` judges.
    As displayed, the relit sky and the direct term do not depend on the gain, so the
    least-squares gain is the one with the smallest error the judge can see for that image
    (docs/sun.md, "Shared images"). Records ``entry["shared"]["gains"]``: the smallest and
    largest gain over lights and channels."""
    own = as_stack(own)
    valid = own.valid
    table = entry["lights"]
    reader = CompactReader(out_dir, entry, own.shape[:2])
    lowest, highest = np.inf, -np.inf
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = reader.lights(chunk)
        for p, column in zip(chunk, own.columns(chunk), strict=True):
            gain = least_squares_gain(decoded[p][valid], column[valid])
            table["scale"][p] = [float32_list(np.asarray(level) * gain)
                                 for level in table["scale"][p]]
            table["offset"][p] = [float32_list(np.asarray(level) * gain)
                                  for level in table["offset"][p]]
            lowest, highest = min(lowest, gain.min()), max(highest, gain.max())
        reader.forget_lights()
    entry["shared"]["gains"] = [round(float(lowest), 4), round(float(highest), 4)]


def least_squares_gain(decoded: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(3,) per channel, the gain ``g >= 0`` that minimizes ``sum (g * decoded - truth)^2``
    over texels (``decoded``, ``truth``: (T, 3)); 1 for a channel whose decoded image is
    zero."""
    decoded = decoded.astype(np.float64)
    power = (decoded**2).sum(axis=0)
    fit = (decoded * truth.astype(np.float64)).sum(axis=0)
    return np.where(power > 0.0, np.clip(fit / np.where(power > 0.0, power, 1.0), 0.0, None),
                    1.0)


def shared_errors(out_dir: Path, entry: dict, own, check: DisplayCheck,
                  budget: float | None) -> dict:
    """What sharing costs a visitor: each sun-path light ``p`` of ``check.lights`` decoded as
    the client decodes it (its group's image with its own scale, ``entry`` after
    :func:`share_entry`) against its *own* master column of ``own`` (H, W, n, 3), as
    displayed under its own display sky with the sun's direct term (``check``, made with
    ``bounce=own``). The images are judged against their group's column
    (:func:`compress_sun_bounce`), so this is the error the budget does not see (docs/sun.md,
    "Shared images"). Returns ``{"max", "median", "worst_light", "lights", "texel_p99",
    "over_budget"}`` (``texel_p99``: max and median of :meth:`DisplayCheck.texel_error`;
    ``over_budget`` with a budget)."""
    own = as_stack(own)
    lights = check.lights
    reader = CompactReader(out_dir, entry, own.shape[:2])
    _, displayed, texel = sun_bounce_errors(reader, own, own.valid, lights, check)
    out = {"max": round(float(displayed.max()), 6),
           "median": round(float(np.median(displayed)), 6),
           "worst_light": int(lights[int(np.argmax(displayed))]),
           "lights": len(lights),
           "texel_p99": max_median(texel)}
    if budget is not None:
        out["over_budget"] = int((displayed > budget).sum())
    return out
