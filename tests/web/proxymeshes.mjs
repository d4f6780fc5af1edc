// The real proxies of a Node case as web/src/proxyrays.js's Proxies: `meshes` [{vertices
// (V, 3) m, faces (F, 3) indices, albedo RGB}], each a three.js mesh with its albedo.
// For the Node scripts of tests/web/test_phoneestimate_js.py.
import * as THREE from 'three';
import { Proxies } from '../../web/src/proxyrays.js';

export function proxiesOf(meshes) {
  return new Proxies(meshes.map((m) => {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.Float32BufferAttribute(m.vertices.flat(), 3));
    g.setIndex(m.faces.flat());
    const mesh = new THREE.Mesh(g);
    mesh.userData.albedo = new THREE.Vector3(...m.albedo);
    return mesh;
  }));
}
