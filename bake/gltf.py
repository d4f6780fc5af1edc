"""Writing ``site.glb``: virtual models, real-world proxies and shadowing planes, with UVs.

Every node carries ``extras.daylit = {role, atlas?, object?}`` and a name the manifest lists:

- ``virtual/<part>`` — a part of the reconstruction; ``TEXCOORD_0`` indexes the ``lightmap``
  atlas. Its material's base colour is the part's albedo.
- ``real/<name>`` — a real-world proxy (drawn as an invisible occluder over a live camera view,
  as a lit surface in the virtual visit); ``TEXCOORD_0`` indexes the ``lightmap`` atlas.
- ``ground`` — the whole ground rectangle.
- ``shadow/<atlas>/<group>`` — shadowing planes of one virtual part (hull atlas) or one ground
  or wall receiver (ground atlas); ``TEXCOORD_0`` indexes that atlas. Zero reflectance, alpha
  blended (Kakuta Eq. 4).

Written with pygltflib; it must pass the Khronos glTF Validator with no errors.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

FLOAT, UINT32 = gl.FLOAT, gl.UNSIGNED_INT


class _Builder:
    """Accumulates one binary buffer and the glTF objects that view it."""

    def __init__(self):
        self.gltf = gl.GLTF2(asset=gl.Asset(generator="daylit bake", version="2.0"))
        self.gltf.scenes = [gl.Scene(nodes=[])]
        self.gltf.scene = 0
        self.blob = bytearray()
        self.materials: dict[tuple, int] = {}

    def _view(self, data: bytes, target: int) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data), target=target)
        )
        self.blob.extend(data)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, bounds: bool = False) -> int:
        if kind == "SCALAR":
            data = np.ascontiguousarray(array, dtype=np.uint32)
            view = self._view(data.tobytes(), gl.ELEMENT_ARRAY_BUFFER)
            component, count = UINT32, data.size
            lo = hi = None
        else:
            data = np.ascontiguousarray(array, dtype=np.float32)
            view = self._view(data.tobytes(), gl.ARRAY_BUFFER)
            component, count = FLOAT, len(data)
            lo = data.min(axis=0).tolist() if bounds else None
            hi = data.max(axis=0).tolist() if bounds else None
        self.gltf.accessors.append(
            gl.Accessor(
                bufferView=view,
                componentType=component,
                count=int(count),
                type=kind,
                min=lo,
                max=hi,
            )
        )
        return len(self.gltf.accessors) - 1

    def material(self, name: str, albedo, blend: bool = False) -> int:
        key = (name, tuple(np.round(albedo, 6)), blend)
        if key not in self.materials:
            self.gltf.materials.append(
                gl.Material(
                    name=name,
                    pbrMetallicRoughness=gl.PbrMetallicRoughness(
                        baseColorFactor=[float(a) for a in albedo] + [1.0],
                        metallicFactor=0.0,
                        roughnessFactor=1.0,
                    ),
                    alphaMode=gl.BLEND if blend else gl.OPAQUE,
                    doubleSided=blend,
                )
            )
            self.materials[key] = len(self.gltf.materials) - 1
        return self.materials[key]

    def node(self, name, vertices, faces, normals, uv, material, extras) -> None:
        attributes = gl.Attributes(
            POSITION=self.accessor(vertices, "VEC3", bounds=True),
            NORMAL=self.accessor(normals, "VEC3"),
        )
        if uv is not None:
            attributes.TEXCOORD_0 = self.accessor(uv, "VEC2")
        primitive = gl.Primitive(
            attributes=attributes,
            indices=self.accessor(faces.ravel(), "SCALAR"),
            material=material,
            mode=gl.TRIANGLES,
        )
        self.gltf.meshes.append(gl.Mesh(name=name, primitives=[primitive]))
        self.gltf.nodes.append(
            gl.Node(name=name, mesh=len(self.gltf.meshes) - 1, extras={"daylit": extras})
        )
        self.gltf.scenes[0].nodes.append(len(self.gltf.nodes) - 1)

    def write(self, path: Path) -> None:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.buffers = [gl.Buffer(byteLength=len(self.blob))]
        self.gltf.set_binary_blob(bytes(self.blob))
        self.gltf.save_binary(str(path))


def write_site_glb(path: Path, site, atlases: dict, albedo_by_part: dict) -> list[dict]:
    """Write the GLB; returns the manifest's ``model.nodes`` list (name, role, atlas, object)."""
    b = _Builder()
    listed: list[dict] = []
    lightmap = atlases["lightmap"]
    roles = {p.name: "virtual" for p in site.virtual}
    roles.update({proxy.part.name: "real" for proxy in site.real})
    for r in lightmap.receivers:
        role = roles[r.name]
        name = f"{role}/{r.name}"
        extras = {"role": role, "atlas": "lightmap", "object": r.object}
        material = b.material(name, albedo_by_part[r.name])
        b.node(
            name,
            r.vertices,
            r.faces,
            r.normals,
            r.atlas_uv(lightmap.width, lightmap.height),
            material,
            extras,
        )
        listed.append({"name": name, **extras})

    g = site.ground.part.mesh
    b.node(
        "ground",
        g.vertices,
        g.faces,
        np.tile([0.0, 1.0, 0.0], (len(g.vertices), 1)),
        None,
        b.material("ground", site.ground.albedo),
        {"role": "ground"},
    )
    listed.append({"name": "ground", "role": "ground"})

    shadow = b.material("shadowing-plane", [0.0, 0.0, 0.0], blend=True)
    for atlas_id in ("hull", "ground"):
        if atlas_id not in atlases:
            continue
        atlas = atlases[atlas_id]
        groups: dict[str, list] = {}
        for r in atlas.receivers:
            # Hull planes of one part form one node; ground and wall receivers one each.
            key = r.name.rsplit("/", 1)[0] if r.kind == "hull" else r.name
            groups.setdefault(key, []).append(r)
        for key, members in groups.items():
            vertices, faces, normals, uv = [], [], [], []
            offset = 0
            for r in members:
                vertices.append(r.vertices)
                faces.append(r.faces + offset)
                normals.append(r.normals)
                uv.append(r.atlas_uv(atlas.width, atlas.height))
                offset += len(r.vertices)
            name = f"shadow/{key}" if key.startswith(("hull/", "ground/", "wall/")) else key
            extras = {"role": "shadowing-plane", "atlas": atlas_id}
            if members[0].object:
                extras["object"] = members[0].object
            b.node(
                name,
                np.concatenate(vertices),
                np.concatenate(faces),
                np.concatenate(normals),
                np.concatenate(uv),
                shadow,
                extras,
            )
            listed.append({"name": name, **extras})
    b.write(path)
    return listed


def read_site_glb(path: Path) -> dict:
    """Read back a GLB written by :func:`write_site_glb`.

    Returns ``{node name: {"vertices", "faces", "normals", "uv" (or None), "extras",
    "albedo"}}`` with the raw attribute values (``uv`` as stored: origin top left).
    """
    gltf = gl.GLTF2().load(str(path))
    blob = gltf.binary_blob()

    def read(index: int | None) -> np.ndarray | None:
        if index is None:
            return None
        accessor = gltf.accessors[index]
        view = gltf.bufferViews[accessor.bufferView]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[accessor.type]
        dtype = np.uint32 if accessor.componentType == UINT32 else np.float32
        start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
        data = np.frombuffer(blob, dtype=dtype, count=accessor.count * width, offset=start)
        return data.reshape(accessor.count, width) if width > 1 else data

    out = {}
    for node in gltf.nodes:
        primitive = gltf.meshes[node.mesh].primitives[0]
        attributes = primitive.attributes
        material = gltf.materials[primitive.material]
        out[node.name] = {
            "vertices": read(attributes.POSITION).astype(np.float64),
            "faces": read(primitive.indices).reshape(-1, 3).astype(np.int64),
            "normals": read(attributes.NORMAL),
            "uv": read(attributes.TEXCOORD_0),
            "extras": (node.extras or {}).get("daylit", {}),
            "albedo": np.array(material.pbrMetallicRoughness.baseColorFactor[:3]),
        }
    return out
