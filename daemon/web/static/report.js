// One job's report: the repair in words, the input and repaired meshes side by side with
// what the repair changed coloured, and the G-code layer by layer.
import { api, actionButtons } from "./app.js";
import { LayerPreview } from "./layers.js";

const $ = (id) => document.getElementById(id);
let current = null;      // the job row shown
let meshJob = null;      // the job whose meshes are loaded
let layerJob = null;
let viewer = null;       // the 3D views (loaded on first use: three.js is large)
let layers = null;

export function reportJobId() { return current ? current.id : null; }

export function closeReport() {
  current = null;
  $("report").hidden = true;
}

export async function openReport(job) {
  current = job;
  meshJob = layerJob = null;
  $("report").hidden = false;
  $("report-title").textContent = `Job ${job.id}: ${job.name}`;
  $("report").scrollIntoView({ behavior: "smooth", block: "start" });
  await refreshReport(job);
}

export async function refreshReport(job) {
  current = job;
  const response = await api(`/api/preflight/jobs/${job.id}`);
  if (!response.ok) return;
  const detail = await response.json();
  if (!current || current.id !== detail.id) return;
  $("report-summary").textContent = summaryWords(detail);
  $("report-text").textContent = detail.text;
  $("report-actions").replaceChildren(actionButtons(detail));
  if (detail.views.mesh && meshJob !== detail.id + detail.state) {
    meshJob = detail.id + detail.state;
    showMeshes(detail);
  }
  $("mesh-section").hidden = !detail.views.mesh;
  if (detail.views.layers && layerJob !== detail.id) {
    layerJob = detail.id;
    showLayers(detail);
  }
  $("layer-section").hidden = !detail.views.layers;
}

function summaryWords(d) {
  const r = d.repair_report;
  const parts = [];
  if (d.kind === "gcode") parts.push("G-code: checked against the build volume and the command policy, not repaired.");
  else if (!r) parts.push(d.state === "failed" ? "" : "Not repaired yet.");
  else if (r.path === "unchanged") parts.push(`The model was already printable: its ${r.before.triangles} triangles are printed unchanged.`);
  else {
    const a = r.after, b = r.before, done = [];
    if (a.intersecting_pairs_resolved) done.push(`${a.intersecting_pairs_resolved} pairs of crossing triangles were resolved`);
    if (a.components_dropped_internal) done.push(`${a.components_dropped_internal} part(s) hidden inside the model were dropped`);
    if (a.internal_triangles_dropped) done.push(`${a.internal_triangles_dropped} internal triangles were removed`);
    if (a.sheet_triangles_thickened) done.push(`${(+a.sheet_area_thickened).toPrecision(3)} mm² of zero-thickness sheet was thickened to ${r.epsilon} mm`);
    if (a.wires_inflated) done.push(`${a.wires_inflated} wire(s) were turned into ${r.epsilon} mm rods`);
    if (r.holes_closed && r.holes_closed.count) done.push(`${r.holes_closed.count} small hole(s) were closed`);
    if (a.degenerate_removed) done.push(`${a.degenerate_removed} collapsed triangles were removed`);
    parts.push(`The model had ${b.triangles} triangles and was not printable. ` +
      (done.length ? done.join("; ") + ". " : "It was closed and re-oriented. ") +
      `The result has ${a.triangles} triangles in ${a.components} part(s), ${(+r.volume).toPrecision(4)} mm³; ` +
      `no point moved more than ${(+r.deviation).toPrecision(2)} mm (ε = ${r.epsilon} mm, the nozzle).`);
  }
  if (d.reason) parts.push(`Outcome: ${d.state} — ${d.reason}.`);
  else if (d.state === "done") parts.push("Printed.");
  return parts.filter(Boolean).join(" ");
}

async function showMeshes(detail) {
  const note = $("mesh-note");
  note.textContent = "Loading the meshes…";
  try {
    if (!viewer) viewer = await import("./viewer.js").then((m) => new m.SideBySide($("view-input"), $("view-repaired"), $("legend")));
    const fetchMesh = async (which) => {
      const r = await api(`/api/preflight/jobs/${detail.id}/mesh/${which}`);
      if (!r.ok) throw new Error((await r.json().catch(() => ({}))).error || `HTTP ${r.status}`);
      return r.arrayBuffer();
    };
    const [input, repaired] = await Promise.all([fetchMesh("input"), fetchMesh("repaired")]);
    viewer.show(input, repaired);
    $("xray").checked = false;
    $("xray").onchange = (e) => viewer.xray(e.target.checked);
    note.textContent = "Drag to turn, pinch or scroll to zoom; both views move together.";
  } catch (e) {
    note.textContent = `The 3D view is not available: ${e.message || e}`;
  }
}

async function showLayers(detail) {
  if (!layers) layers = new LayerPreview($("layer-canvas"), $("layer-slider"), $("layer-label"), $("layer-legend"), api);
  await layers.load(detail.id);
}
