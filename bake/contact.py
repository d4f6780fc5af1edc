"""Contact lines: the texels of a surface that straddle the foot of a wall or a corner.

A receiver's texel is one sample at its centre, and the client reads the surface bilinearly
between texel centres. Where a wall stands on the ground, the ground texels whose centres lie
under the wall are *buried*: no light reaches them. Read bilinearly, a visible ground point
5 cm from the wall's face mixes up to half of such a dark texel into its value: the demo's
ground was 41 % too dark 5 cm from a wall and 8-9 % within 0.5 m (issue 20).

Method: **buried texel centres moved off the buried region, then extrapolated along the
chord** (docs/architecture.md, "Contact lines"; figures in docs/benchmarks.md).

1. Before tracing (:func:`move_buried_samples`), a texel whose centre sees only back faces
   (inside a solid) and has a visible neighbour ``o`` on its surface (8-connected) casts a
   ray from its centre ``b`` toward ``o``'s centre; where the ray leaves the solid (a back
   face) at ``c``, just outside it, becomes the texel's sample point. Of several visible
   neighbours the one reached soonest is used.
2. After tracing (:func:`extrapolate_direct`), the texel's direct light is the chord through
   the two traced values, ``E(c)`` at the contact line and ``E(o)``, extended to ``b``:
   ``E_b = E(o) + (E(c) - E(o)) |o - b| / |o - c|``. Read bilinearly between ``b`` and
   ``o``, the surface then matches the light field at both ends of its visible part, and in
   between to within the field's curvature over that part. Worst reading 5 cm from a wall
   under a uniform sky, the foot anywhere in a 0.5 m texel (docs/benchmarks.md): 0.02 % (3 m
   wall) and 0.06 % (2 m), against 1.3 % and 3.8 % for a plane continued from the visible
   texels alone, and 3.4 % and 5.0 % for the value at the contact line alone.
3. The bounce is smoothed over the visible texels only (bake.denoise), never across the
   contact line; within ``NEAR_RINGS`` texels of buried ones with a narrower kernel
   (``NEAR_SIGMA_TEXELS``), as the bounce bends there (beside a 3 m wall of albedo 0.6 the
   1.5-texel fit read 9-15 % low 5 cm from the wall, the 1-texel one 2-9 %). A moved texel
   keeps the bounce traced at its contact line (a fit continued to its centre read 8 % low
   there), smoothed along its strip of moved texels only; the other buried texels next to
   visible ones hold the fit continued (:func:`continue_into_buried`), the rest the nearest
   of those.
4. Before tracing, the bounce cache gets finer points along contact lines
   (:func:`refine_cache`): a bounce hit reads the nearest lit cache point on its face, and
   in a wall's dark foot or an inner corner every lit neighbour lay farther out, in brighter
   light (the test courtyard's ground 25 cm from both walls read 4.5 % bright, now 0.5 %;
   5 cm from both 17.9 %, then 12.1 %: the rest was the buried texels under the second wall,
   whose end lies inside the first, taken for visible; found since, +1.6 %,
   docs/architecture.md "Contact lines").

Limits: a wall thinner than a texel has visible texels on both sides of one buried texel,
which holds one value for both (the side reached soonest); finer texels along contact lines
would lift that but need a second texture per atlas in the client and the compressor (not
taken). Hull planes (3 cm outside the virtual objects) are left as they are.
"""

from __future__ import annotations

import numpy as np

from bake.denoise import MomentBlurs, channel_blocks, fitted_values, plane_weights
from bake.labelgroups import continuation_fits, label_boxes

# False: texels at contact lines are treated as before issue 20 (buried texels dark, their
# bounce the nearest open texel's): benchmarks/bench_contact.py's "before", in one run.
ENABLED = True
PROBE_RAYS = 16  # a texel centre is buried when its probe rays hit back faces (all; most: checked)
MOST_BACK = 10  # of PROBE_RAYS on back faces: the crossing count decides (move_buried_samples)
OUTSIDE_M = 0.005  # a moved sample point lies this far past where its ray leaves the solid
MAX_EXIT_FRACTION = 0.9  # beyond this share of the way to the neighbour: left buried
RINGS = 1  # buried texels within this many texels (8-connected) of visible ones are continued
FIT_SIGMA_TEXELS = 1.0  # the fit reads mostly the two nearest visible texels in each direction
NEAR_RINGS = 3  # visible texels this close to buried ones get the narrower bounce smoothing
NEAR_SIGMA_TEXELS = 1.0
MAX_CROSSINGS = 16  # faces followed along a probe ray to count the solids its origin is in
CROSSING_STEP_M = 1e-4  # past a face hit before looking for the next
# Near contact lines the bounce cache gets points this many times denser (refine_cache).
CACHE_REFINE = 4
LATTICE_PROBE_M = 1e-3  # a lattice node finds its face by a ray from this far above it
CLOSED_SHARE = 0.1  # a cache point this much closed in within the spacing is near a contact


def continue_into_buried(image: np.ndarray, labels: np.ndarray,
                         sigma_px: float = FIT_SIGMA_TEXELS, rings: int = RINGS,
                         plan: dict | None = None) -> np.ndarray:
    """Continue each surface's visible values into its buried texels along contact lines.

    Parameters
    ----------
    image : (H, W, ...) float, per-texel values (irradiance per unit light radiance)
    labels : (H, W) int; a visible texel of surface ``s`` is ``s >= 0``, a buried one
        ``-2 - s``, no texel -1 (bake.writers._open_labels)
    sigma_px : the Gaussian of the local plane fit, texels
    rings : how far (8-connected texels) from a visible texel a buried one is continued
    plan : a dict kept by a caller that continues several images with the same ``labels``
        (a stack's blocks of lights): the fits' texels and weights, (K,) per texel, made
        on the first call (the same values)

    Returns a new float32 array like ``image``: buried texels within ``rings`` of visible
    texels of their surface hold the fitted plane's value at their centre (never below 0);
    every other texel is unchanged. Each surface is fitted in the window its buried texels
    span, or, where those windows add up to many images (the palace's lightmap), in groups
    of surfaces' pieces that one blur fits (:func:`bake.labelgroups.continuation_fits`:
    the same bits).
    """
    if not ENABLED:
        return np.array(image, dtype=np.float32, copy=True)
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    blurs = MomentBlurs(sigma_px)
    key = (sigma_px, rings)
    fits = None if plan is None else plan.get(key)
    if fits is None:
        fits = _continuation_weights(labels, rings, blurs, sigma_px)
        if plan is not None:
            fits = plan[key] = list(fits)
    for (y0, y1, x0, x1), visible, targets, weights in fits:
        mask, target = _fit_images((y1 - y0, x1 - x0), visible, targets)
        for c0, c1 in channel_blocks(flat.shape[2], mask.size):
            region = flat[y0:y1, x0:x1, c0:c1] * mask[:, :, None].astype(np.float32)
            value = fitted_values(region, weights, blurs, target)
            out[y0:y1, x0:x1, c0:c1][target] = np.maximum(value, 0.0)
    return out.reshape(image.shape)


def _fit_images(shape: tuple, visible: np.ndarray, targets: np.ndarray):
    """A fit's mask (``shape``, float64: 1 at its ``visible`` texels) and its targets
    (bool); ``visible`` and ``targets`` flat indices into the box, from
    :func:`bake.labelgroups.continuation_fits`."""
    mask = np.zeros(shape)
    mask.flat[visible] = 1.0
    target = np.zeros(shape, bool)
    target.flat[targets] = True
    return mask, target


def _continuation_weights(labels, rings: int, blurs: MomentBlurs, sigma_px: float):
    """Per fit of :func:`bake.labelgroups.continuation_fits`: its box, visible texels,
    targets and plane-fit weights (:func:`plane_weights`)."""
    for box, visible, targets in continuation_fits(labels, blurs.radius, rings):
        mask, target = _fit_images((box[1] - box[0], box[3] - box[2]), visible, targets)
        yield box, visible, targets, plane_weights(mask, target, blurs, sigma_px)


def continued_labels(labels: np.ndarray, rings: int = RINGS) -> np.ndarray:
    """(H, W) bool: the texels that hold visible values after :func:`continue_into_buried`
    (visible texels and the buried ones it continued)."""
    import cv2

    out = labels >= 0
    if not ENABLED:
        return out
    h, w = labels.shape
    surface = np.where(labels <= -2, -2 - labels, labels)
    boxes = label_boxes(surface)
    for label in np.unique(labels[labels <= -2]):
        label = -2 - label
        # Within the surface's box grown by ``rings``: the dilation reaches no farther.
        rows, columns = boxes[label]
        y0, y1 = max(rows.start - rings, 0), min(rows.stop + rings, h)
        x0, x1 = max(columns.start - rings, 0), min(columns.stop + rings, w)
        visible = (labels[y0:y1, x0:x1] == label).astype(np.uint8)
        near = cv2.dilate(visible, np.ones((3, 3), np.uint8), iterations=rings) > 0
        out[y0:y1, x0:x1] |= near & (surface[y0:y1, x0:x1] == label)
    return out


def move_buried_samples(atlas, scene, overlaps: bool = True) -> None:
    """Move the sample points of buried texels next to visible ones onto the contact line
    (step 1 of the module's method); sets ``atlas.contact`` for :func:`extrapolate_direct`.

    Parameters
    ----------
    atlas : bake.receivers.Atlas, its ``points`` (T, 3) changed in place for the moved texels
    scene : bake.raytrace.RayScene with everything that can bury a texel (configuration all)
    overlaps : also find texels buried under overlapping solids (``MOST_BACK`` and the
        crossing count); False: only texels all of whose probe rays meet back faces

    ``atlas.contact``: ``{"texel": (m,) int, "neighbour": (m,) int, "extrapolation": (m,)
    float}``: the moved texels, the visible neighbour each was moved toward, and
    ``|o - b| / |o - c|`` (at least 1).
    """
    from bake import tracing_loops as loops
    from bake.cachepoints import lattice
    from bake.raytrace import RAY_OFFSET_M

    empty = {"texel": np.zeros(0, np.int64), "neighbour": np.zeros(0, np.int64),
             "extrapolation": np.zeros(0)}
    atlas.contact = empty
    T = atlas.count
    if T == 0 or not ENABLED:
        return
    points = np.ascontiguousarray(atlas.points, dtype=np.float64)
    normals = np.ascontiguousarray(atlas.normals, dtype=np.float64)
    origins = np.empty((T * PROBE_RAYS, 3), np.float32)
    dirs = np.empty_like(origins)
    loops.cosine_weighted_rays(points, normals, lattice(PROBE_RAYS), np.zeros((T, 2)),
                               RAY_OFFSET_M, origins, dirs)
    face, _ = scene.first_hit(origins, dirs)
    back = np.zeros(len(face), bool)
    hit = face >= 0
    back[hit] = np.einsum("ij,ij->i", dirs[hit], scene.face_normals[face[hit]]) > 0.0
    back_count = back.reshape(T, PROBE_RAYS).sum(axis=1)
    buried = back_count == PROBE_RAYS
    # Most but not all: where one solid's end lies inside another (the test courtyard's second
    # wall), rays from under the first run inside it into the overlap and meet the other's
    # face from the front. Those texels are judged by the crossing count (buried_points),
    # which counts overlapping solids right; alone it took a visible texel at the demo's hall
    # foot for buried (solid_depth), so it only decides where MOST_BACK rays met back faces
    # (a texel centred on an edge between two solids meets about half).
    if overlaps:
        doubt = np.flatnonzero((back_count >= MOST_BACK) & ~buried)
        if len(doubt):
            buried[doubt] = buried_points(scene, points[doubt], normals[doubt])
    if not buried.any():
        return
    index = np.full((atlas.height, atlas.width), -1, np.int64)
    index[atlas.texels[:, 1], atlas.texels[:, 0]] = np.arange(T)
    pairs_b, pairs_o = [], []
    b = np.flatnonzero(buried)
    x, y = atlas.texels[b, 0], atlas.texels[b, 1]
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == dy == 0:
                continue
            yy, xx = y + dy, x + dx
            inside = (yy >= 0) & (yy < atlas.height) & (xx >= 0) & (xx < atlas.width)
            o = np.full(len(b), -1)
            o[inside] = index[yy[inside], xx[inside]]
            ok = o >= 0
            ok[ok] &= ~buried[o[ok]] & (atlas.labels[o[ok]] == atlas.labels[b[ok]])
            pairs_b.append(b[ok])
            pairs_o.append(o[ok])
    pb, po = np.concatenate(pairs_b), np.concatenate(pairs_o)
    if len(pb) == 0:
        return
    span = points[po] - points[pb]
    length = np.linalg.norm(span, axis=1)
    direction = span / length[:, None]
    face, distance = scene.first_hit(points[pb] + RAY_OFFSET_M * normals[pb], direction)
    leaves = face >= 0
    leaves[leaves] = np.einsum("ij,ij->i", direction[leaves],
                               scene.face_normals[face[leaves]]) > 0.0
    fraction = np.where(leaves, (distance + OUTSIDE_M) / length, np.inf)
    usable = fraction <= MAX_EXIT_FRACTION
    pb, po, fraction, direction = pb[usable], po[usable], fraction[usable], direction[usable]
    length = length[usable]
    # The neighbour reached soonest, per buried texel (ties: the first in scan order).
    order = np.lexsort((np.arange(len(pb)), fraction, pb))
    first = np.ones(len(order), bool)
    first[1:] = pb[order][1:] != pb[order][:-1]
    chosen = order[first]
    texel, neighbour = pb[chosen], po[chosen]
    f = fraction[chosen]
    atlas.points = atlas.points.copy()
    atlas.points[texel] = points[texel] + (f * length[chosen])[:, None] * direction[chosen]
    atlas.contact = {"texel": texel, "neighbour": neighbour, "extrapolation": 1.0 / (1.0 - f)}


def solid_depth(scene, origins: np.ndarray, directions: np.ndarray):
    """How many closed solids each ray's origin lies in, and where the ray leaves them all.

    Parameters
    ----------
    scene : bake.raytrace.RayScene
    origins, directions : (m, 3) metres, unit

    Returns ``depth`` (m,) int and ``exit_m`` (m,) float: along each ray, every back face
    hit is leaving a solid (+1) and every front face entering one (-1); their sum over the
    whole ray is the depth of its origin, and ``exit_m`` the distance of the hit after which
    the ray is in none (inf where the depth is not above 0). Why not the first hit alone:
    where solids overlap (the end of one wall inside another), a point inside both sees
    the inner one's faces from the front, and a texel under the second wall of the test
    courtyard was taken for visible (its ground read 4.3 % bright 5 cm from that wall). A
    ray still hitting after :data:`MAX_CROSSINGS` keeps its first hit's answer (a back face:
    depth 1, leaving there). Faces that coincide (two solids' faces in one plane) are met as
    one, so a ray crossing them can be counted one off: callers take a vote of several rays.

    Used by bake.receivers.drop_buried and :func:`buried_points` (the bounce cache's
    refinement), with the rays turned upward. By :func:`move_buried_samples` only where most
    of its first hits are back faces: alone, its vote over rays about a texel's normal took a
    visible texel at the demo's hall foot for buried (docs/architecture.md, "Contact
    lines").
    """
    m = len(origins)
    signs = np.zeros((m, MAX_CROSSINGS), np.int64)
    dist = np.full((m, MAX_CROSSINGS), np.inf)
    at = np.array(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    travelled = np.zeros(m)
    active = np.arange(m)
    for k in range(MAX_CROSSINGS + 1):
        if len(active) == 0:
            break
        face, d = scene.first_hit(at[active], directions[active])
        hit = face >= 0
        active, face, d = active[hit], face[hit], d[hit]
        if k == MAX_CROSSINGS:
            break  # these rays are left with their first hit's answer
        back = np.einsum("ij,ij->i", directions[active], scene.face_normals[face]) > 0.0
        signs[active, k] = np.where(back, 1, -1)
        dist[active, k] = travelled[active] + d
        # Past the face, so that it is not hit again.
        travelled[active] += d + CROSSING_STEP_M
        at[active] += (d + CROSSING_STEP_M)[:, None] * directions[active]
    depth = signs.sum(axis=1)
    unresolved = np.zeros(m, bool)
    unresolved[active] = True
    depth[unresolved] = np.maximum(signs[unresolved, 0], 0)
    # The exit: the first crossing at which the running sum reaches the depth.
    reached = (np.cumsum(signs, axis=1) == depth[:, None]) & (depth[:, None] > 0)
    reached[unresolved, 1:] = False
    first = np.argmax(reached, axis=1)
    exit_m = np.where(reached.any(axis=1), dist[np.arange(m), first], np.inf)
    return depth, exit_m


def extrapolate_direct(atlas, direct: np.ndarray) -> np.ndarray:
    """Step 2 of the module's method: the traced direct light (T, ...) of an atlas with each
    moved texel's value extended along the chord from its neighbour's through its own
    (traced at the contact line) to its centre. A new array.

    Linear in the lights, so not clamped per light: a low patch toward the wall is hidden at
    the contact line and seen at the neighbour, and its extended value at the buried centre
    is below 0; clamped, the reading 5 cm from a wall under a uniform sky was 1.9 % high. Every
    visible point between the contact line and the neighbour still reads a mix of the two
    traced values, never below 0."""
    contact = getattr(atlas, "contact", None)
    out = np.array(direct, dtype=np.float32, copy=True)
    if not contact or len(contact["texel"]) == 0:
        return out
    b, o = contact["texel"], contact["neighbour"]
    t = contact["extrapolation"].reshape((-1,) + (1,) * (out.ndim - 1))
    out[b] = out[o] + (out[b] - out[o]) * t
    return out


def near_contact(labels: np.ndarray, rings: int = NEAR_RINGS) -> np.ndarray:
    """(H, W) bool: visible texels (label >= 0) within ``rings`` texels (8-connected) of a
    buried one (label <= -2); none when contact lines are off (:data:`ENABLED`)."""
    import cv2

    buried = (labels <= -2).astype(np.uint8)
    if not ENABLED or not buried.any():
        return np.zeros(labels.shape, bool)
    grown = cv2.dilate(buried, np.ones((3, 3), np.uint8), iterations=rings) > 0
    return grown & (labels >= 0)


def buried_points(scene, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m,) bool: points (m, 3) on surfaces with unit ``normals`` (m, 3) that lie inside a
    solid: most of :data:`PROBE_RAYS` rays from just above them cross more back faces than
    front ones (:func:`solid_depth`). The rays are turned upward: where a point lies does
    not depend on the direction it is probed in, and a downward ray meets the ground (an
    open surface) and a part's underside on it in one place, either first."""
    from bake import tracing_loops as loops
    from bake.cachepoints import lattice
    from bake.raytrace import RAY_OFFSET_M

    m = len(points)
    if m == 0:
        return np.zeros(0, bool)
    origins = np.empty((m * PROBE_RAYS, 3), np.float32)
    dirs = np.empty_like(origins)
    loops.cosine_weighted_rays(np.ascontiguousarray(points, np.float64),
                               np.ascontiguousarray(normals, np.float64), lattice(PROBE_RAYS),
                               np.zeros((m, 2)), RAY_OFFSET_M, origins, dirs)
    dirs[:, 1] = np.abs(dirs[:, 1])
    depth, _ = solid_depth(scene, origins, dirs)
    return (depth > 0).reshape(m, PROBE_RAYS).mean(axis=1) > 0.5


def refine_cache(geometry, scene, points, normals, faces, spacing_m: float):
    """Bounce-cache points added near contact lines: ``(points, normals, faces)`` with, on
    every face, the nodes of a lattice of ``spacing_m / CACHE_REFINE`` within twice
    ``spacing_m`` of a cache point of that face near a contact line (the seeds: one per
    ``spacing_m^2`` or so, the disc covers the gaps between them) that are near a contact
    line themselves and not buried. A point is near a contact line when at least
    :data:`CLOSED_SHARE` of its probe rays (about its normal) meet a surface within
    ``spacing_m`` (a wall's foot seen from the ground or from the wall, an inner corner;
    not a wall's top edge); a buried cache point is a seed too.

    Why: a bounce ray's hit reads the nearest lit cache point on its face
    (bake.irradiance.BounceCache), and next to where a surface runs into a solid (a wall's
    foot, the inner corner of an L) every lit neighbour lies farther out, in brighter light:
    the bounce read there is too high. At the test courtyard's inner corner (cache spacing
    1 m), with its buried texels found by the crossing count (branch s21-corner, since
    reverted), the ground 5 cm from both walls read 6.7 % bright, its direct light within
    1 % of the paths reference: the excess was all bounce (+16 %); with a 0.25 m cache
    everywhere, 2.4 %; refined so, 2.2 % (on today's texels 17.9 -> 12.8 %, 25 cm from both
    walls 4.5 -> 0.5 %). The lattice goes only where contact lines are. Deterministic (no random
    numbers): the lattice is fixed to each face.

    Parameters
    ----------
    geometry : bake.raytrace.Geometry; scene : its bake.raytrace.RayScene (configuration all)
    points, normals : (C, 3) the cache points (metres) and their face normals; faces : (C,)
    spacing_m : the cache's spacing near the site

    Returns the arrays extended by the added points (the first C rows unchanged).
    """
    if not ENABLED or len(points) == 0:
        return points, normals, faces
    buried = buried_points(scene, points, normals)
    seeds = buried | _closed_in(scene, points, normals, spacing_m)
    if not seeds.any():
        return points, normals, faces
    fine_m = spacing_m / CACHE_REFINE
    # The lattice is the plane's, not the triangle's: coplanar triangles (the two of a wall's
    # face) share its nodes, so a seed's disc runs on across their edges.
    n = normals[seeds]
    t1 = np.where(np.abs(n[:, 1:2]) < 0.9, np.cross(n, [0.0, 1.0, 0.0]),
                  np.cross(n, [1.0, 0.0, 0.0]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    p = points[seeds]
    plane = np.round(np.c_[n, np.einsum("ij,ij->i", n, p)] * 1e6).astype(np.int64)
    iu0 = np.floor(np.einsum("ij,ij->i", p, t1) / fine_m).astype(np.int64)
    iv0 = np.floor(np.einsum("ij,ij->i", p, t2) / fine_m).astype(np.int64)
    k = 2 * CACHE_REFINE
    du, dv = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    near = (du**2 + dv**2) <= k * k  # within twice spacing_m of the seed
    du, dv = du[near], dv[near]
    nodes = np.concatenate([np.repeat(plane, len(du), axis=0),
                            (iu0[:, None] + du).reshape(-1, 1),
                            (iv0[:, None] + dv).reshape(-1, 1)], axis=1)
    nodes = np.unique(nodes, axis=0)  # neighbouring seeds share lattice nodes
    n = nodes[:, :3] / 1e6
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t1 = np.where(np.abs(n[:, 1:2]) < 0.9, np.cross(n, [0.0, 1.0, 0.0]),
                  np.cross(n, [1.0, 0.0, 0.0]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    cand = (n * (nodes[:, 3:4] / 1e6) + ((nodes[:, 4:5] + 0.5) * fine_m) * t1
            + ((nodes[:, 5:6] + 0.5) * fine_m) * t2)
    # The face under each node: a short ray back onto the plane (none: off the surface).
    face, d = scene.first_hit(cand + LATTICE_PROBE_M * n, -n)
    on = (face >= 0) & (np.abs(d - LATTICE_PROBE_M) < 0.1 * LATTICE_PROBE_M)
    on[on] &= np.einsum("ij,ij->i", geometry.face_normals[face[on]], n[on]) > 0.999
    cand, nf = cand[on], face[on]
    cand_normals = geometry.face_normals[nf]
    keep = _closed_in(scene, cand, cand_normals, spacing_m)  # the band along the contact
    cand, nf, cand_normals = cand[keep], nf[keep], cand_normals[keep]
    lit = ~buried_points(scene, cand, cand_normals)
    return (np.concatenate([points, cand[lit]]), np.concatenate([normals, cand_normals[lit]]),
            np.concatenate([faces, nf[lit]]))


def _closed_in(scene, points: np.ndarray, normals: np.ndarray, range_m: float) -> np.ndarray:
    """(m,) bool: at least :data:`CLOSED_SHARE` of :data:`PROBE_RAYS` cosine-weighted rays
    from each point (m, 3) about its normal (m, 3) hit a surface within ``range_m``."""
    from bake import tracing_loops as loops
    from bake.cachepoints import lattice
    from bake.raytrace import RAY_OFFSET_M

    m = len(points)
    origins = np.empty((m * PROBE_RAYS, 3), np.float32)
    dirs = np.empty_like(origins)
    loops.cosine_weighted_rays(np.ascontiguousarray(points, np.float64),
                               np.ascontiguousarray(normals, np.float64), lattice(PROBE_RAYS),
                               np.zeros((m, 2)), RAY_OFFSET_M, origins, dirs)
    face, d = scene.first_hit(origins, dirs)
    close = (face >= 0) & (d <= range_m)
    return close.reshape(m, PROBE_RAYS).mean(axis=1) >= CLOSED_SHARE
