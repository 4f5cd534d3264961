// The input and the repaired mesh side by side (three.js), each face coloured by what the
// repair did to it; the two cameras move together.
import * as THREE from "three";
import { OrbitControls } from "three/addons/OrbitControls.js";

// The labels of repair/changes.py, in its order.
export const LABELS = [
  { name: "kept", text: "kept as it was", colour: 0x9aa7bd },
  { name: "re-cut", text: "re-cut where parts met", colour: 0x38bdf8 },
  { name: "thickened", text: "thickened sheet or wire", colour: 0xf59e0b },
  { name: "added", text: "added (lids, mended)", colour: 0xd946ef },
  { name: "dropped", text: "dropped (internal)", colour: 0xef4444 },
];

export function parseMesh(buffer) {
  const head = new DataView(buffer, 0, 8);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== "PFM1") throw new Error("not a preflight mesh");
  const n = head.getUint32(4, true);
  const positions = new Float32Array(buffer.slice(8, 8 + n * 36));
  const labels = new Uint8Array(buffer, 8 + n * 36, n);
  const counts = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8 + n * 37)) || "{}");
  return { n, positions, labels, counts };
}

function geometry(mesh) {
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(mesh.positions, 3));
  const colours = new Float32Array(mesh.n * 9);
  const palette = LABELS.map((l) => new THREE.Color(l.colour));
  for (let i = 0; i < mesh.n; i++) {
    const c = palette[mesh.labels[i]] || palette[0];
    for (let k = 0; k < 3; k++) colours.set([c.r, c.g, c.b], i * 9 + k * 3);
  }
  g.setAttribute("color", new THREE.BufferAttribute(colours, 3));
  g.computeVertexNormals();
  g.computeBoundingBox();
  return g;
}

class View {
  constructor(container) {
    this.container = container;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.setClearColor(0x1f2533);
    container.replaceChildren(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x444455, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.8);
    sun.position.set(1, -1.5, 2);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(35, 4 / 3, 0.1, 10000);
    this.camera.up.set(0, 0, 1);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.enableDamping = false;
    this.material = new THREE.MeshStandardMaterial({ vertexColors: true, flatShading: true,
      side: THREE.DoubleSide, roughness: 0.7, metalness: 0.05 });
    this.mesh = null;
    new ResizeObserver(() => this.resize()).observe(container);
  }

  resize() {
    const w = this.container.clientWidth, h = this.container.clientHeight;
    if (!w || !h) return;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  setMesh(geom, box) {
    if (this.mesh) { this.scene.remove(this.mesh); this.mesh.geometry.dispose(); }
    this.mesh = new THREE.Mesh(geom, this.material);
    this.scene.add(this.mesh);
    if (this.grid) { this.scene.remove(this.grid); this.grid.geometry.dispose(); }
    // a grid under the part: the bed it stands on, and a sense of its size
    const size = box.getSize(new THREE.Vector3());
    const widest = Math.max(size.x, size.y, 1e-3);
    const step = 10 ** Math.floor(Math.log10(widest / 2));  // 1, 10 or 100 mm: a few squares
    const span = Math.ceil((widest * 1.6) / step) * step;
    this.grid = new THREE.GridHelper(span, span / step, 0x56607a, 0x3a4254);
    this.grid.rotation.x = Math.PI / 2;  // three's grid lies in XZ; the bed is XY
    const centre = box.getCenter(new THREE.Vector3());
    this.grid.position.set(centre.x, centre.y, box.min.z);
    this.scene.add(this.grid);
  }

  render() { this.renderer.render(this.scene, this.camera); }
}

export class SideBySide {
  constructor(inputBox, repairedBox, legendBox) {
    this.views = [new View(inputBox), new View(repairedBox)];
    this.legend = legendBox;
    for (const [i, view] of this.views.entries()) {
      view.controls.addEventListener("change", () => this.follow(i));
    }
  }

  follow(leader) {
    const a = this.views[leader], b = this.views[1 - leader];
    if (this.syncing) return;
    this.syncing = true;
    b.camera.position.copy(a.camera.position);
    b.controls.target.copy(a.controls.target);
    b.controls.update();
    this.syncing = false;
    a.render(); b.render();
  }

  show(inputBuffer, repairedBuffer) {
    const meshes = [parseMesh(inputBuffer), parseMesh(repairedBuffer)];
    const geometries = meshes.map(geometry);
    const box = new THREE.Box3();
    for (const g of geometries) box.union(g.boundingBox);
    geometries.forEach((g, i) => this.views[i].setMesh(g, box));
    const centre = box.getCenter(new THREE.Vector3());
    const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-3);
    for (const view of this.views) {
      view.controls.target.copy(centre);
      view.camera.position.set(centre.x + radius * 1.9, centre.y - radius * 2.6, centre.z + radius * 1.6);
      view.camera.near = radius / 100;
      view.camera.far = radius * 100;
      view.resize();
      view.controls.update();
      view.render();
    }
    this.showLegend(meshes);
  }

  showLegend(meshes) {
    const used = new Set();
    for (const m of meshes) for (const name of Object.keys(m.counts)) used.add(name);
    this.legend.replaceChildren(...LABELS.filter((l) => used.has(l.name) || l.name === "kept").map((l) => {
      const span = document.createElement("span");
      span.style.setProperty("--swatch", `#${l.colour.toString(16).padStart(6, "0")}`);
      const n = meshes.map((m) => m.counts[l.name] || 0);
      span.textContent = `${l.text} (${n[0]} in, ${n[1]} out)`;
      return span;
    }));
  }

  xray(on) {
    const m = this.views[0].material;
    m.transparent = on;
    m.opacity = on ? 0.35 : 1;
    m.depthWrite = !on;
    m.needsUpdate = true;
    this.views[0].render();
  }
}
