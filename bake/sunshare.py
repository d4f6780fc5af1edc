"""Neighbouring sun-path patches sharing one sun-bounce image (docs/sun.md, "Shared
images"): which patches share (:class:`SharedImages`, grouped by a coarser dome's patches),
the columns their images are made of (:class:`SharedColumns`), the patches taken out of
their groups where sharing would show (:func:`groups_within`) and the gain that fits a
member's image to its own column (:func:`least_squares_gain`). bake.sunbounce encodes the
images; bake.sundisplay judges them; bake.sunwritten reads them back, gives each member its
gain and measures what sharing costs each patch as displayed.
Moved out of bake/sunbounce.py on 2026-12-07 (the module had grown past 500 lines).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bake.quantize import float32_list
from bake.rowstore import as_stack
from bake.sundisplay import SUN_BOUNCE_DECODE_CHUNK, TEXEL_BOUND_PER_BUDGET, DisplayCheck

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
    gain per channel (bake.sunwritten.read_back)."""

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
        """(len(lights), H, W, 3) float32: each light's group column. Every member of every
        group asked for is read in one call: a stack on disk reads each of its block files
        whole for a call (bake.rowstore.StackStore.columns)."""
        groups = [self.shared.groups.get(int(p), [int(p)]) for p in lights]
        wanted = sorted({q for members in groups for q in members})
        own = dict(zip(wanted, self.image.columns(wanted), strict=True))
        return np.stack([self.group_column(int(p), members, own)
                         for p, members in zip(lights, groups, strict=True)])

    def group_column(self, light: int, members: list[int], own: dict) -> np.ndarray:
        """(H, W, 3) float32 ``light``'s group column from its ``members``' own columns
        ``own`` {member: (H, W, 3)}: summed in float64 in the members' order and scaled to
        ``light``'s solid angle."""
        omega = self.shared.solid_angles_sr
        total = np.zeros(self.shape[:2] + (3,), dtype=np.float64)
        for q in members:
            total += own[q]
        return (total * (omega[light] / omega[members].sum())).astype(np.float32)

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
            table["scale"][q] = scaled_levels(table["scale"][rep], f)
            table["offset"][q] = scaled_levels(table["offset"][rep], f)
    table["image"] = shared.image_of(n)
    entry["shared"] = {"kind": shared.kind, "frequency": shared.frequency,
                       "images": len(shared.groups),
                       "lights": sum(len(m) for m in shared.groups.values())}
    return entry


def scaled_levels(levels: list, factor) -> list:
    """A light's ``scale`` or ``offset`` (one list of 3 per level) times ``factor`` (a number
    or (3,) per channel), as the manifest stores them (:func:`float32_list`)."""
    return [float32_list(np.asarray(level) * factor) for level in levels]


def groups_within(shared: SharedImages, own, check: DisplayCheck, budget: float
                  ) -> SharedImages:
    """``shared`` with the patches that sharing would put over :data:`SHARING_SHARE` of
    ``budget`` as displayed taken out of their groups, each to an image of its own: in each
    group, the group's column (the members' solid-angle mean) times each member's
    least-squares gain (:func:`least_squares_gain`, as bake.sunwritten.read_back will give
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
    groups: dict[int, list[int]] = {}
    for reps in group_batches(list(shared.groups), shared.groups):
        batch = [list(shared.groups[rep]) for rep in reps]
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


def group_batches(reps: list[int], groups: dict[int, list[int]]) -> list[list[int]]:
    """``reps`` in batches of whole groups (``groups`` {rep: members}; a rep not in it is a
    group of one) of about :data:`SUN_BOUNCE_DECODE_CHUNK` members: a batch's columns are
    read at once, since a stack on disk reads every row of a block of lights for each call
    (bake.rowstore.StackStore.columns)."""
    batches: list[list[int]] = [[]]
    size = 0
    for rep in reps:
        members = len(groups.get(rep, [rep]))
        if batches[-1] and size + members > SUN_BOUNCE_DECODE_CHUNK:
            batches.append([])
            size = 0
        batches[-1].append(rep)
        size += members
    return batches


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


def least_squares_gain(decoded: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(3,) per channel, the gain ``g >= 0`` that minimizes ``sum (g * decoded - truth)^2``
    over texels (``decoded``, ``truth``: (T, 3)); 1 for a channel whose decoded image is
    zero."""
    decoded = decoded.astype(np.float64)
    power = (decoded**2).sum(axis=0)
    fit = (decoded * truth.astype(np.float64)).sum(axis=0)
    return np.where(power > 0.0, np.clip(fit / np.where(power > 0.0, power, 1.0), 0.0, None),
                    1.0)
