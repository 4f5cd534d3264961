// The status page: the daemon's state pushed by server-sent events, the job actions and
// uploads behind the API key, and each job's report (3D view and layer preview).
import { openReport, closeReport, refreshReport, reportJobId } from "./report.js";

const KEY_ITEM = "preflight.apiKey";
const $ = (id) => document.getElementById(id);
let apiKey = localStorage.getItem(KEY_ITEM) || "";
let events = null;
let lastState = null;

export function keyHeader() { return { "X-Api-Key": apiKey }; }

export async function api(path, options = {}) {
  const response = await fetch(path, { ...options, headers: { ...keyHeader(), ...(options.headers || {}) } });
  if (response.status === 401) askKey("The key was refused: paste the current one.");
  return response;
}

export function toast(text, bad = false) {
  const t = $("toast");
  t.textContent = text;
  t.className = "toast show" + (bad ? " bad" : "");
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => { t.className = "toast"; }, 4500);
}

export function duration(seconds) {
  if (seconds == null || !isFinite(seconds)) return "?";
  const s = Math.round(seconds), h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60);
  if (h) return `${h} h ${String(m).padStart(2, "0")} min`;
  return m ? `${m} min ${String(s % 60).padStart(2, "0")} s` : `${s % 60} s`;
}

function el(tag, props = {}, ...children) {
  const { dataset, style, ...rest } = props;
  const node = Object.assign(document.createElement(tag), rest);
  if (dataset) Object.assign(node.dataset, dataset);
  if (style) node.style.cssText = style;
  for (const c of children) if (c != null) node.append(c);
  return node;
}

// -- the key -------------------------------------------------------------------------------
function askKey(message = "") {
  const dialog = $("key-dialog");
  $("key-error").textContent = message;
  $("key-input").value = "";
  if (!dialog.open) dialog.showModal();
}

$("key-form").addEventListener("submit", (event) => {
  if (event.submitter && event.submitter.value !== "save") return;
  const value = $("key-input").value.trim();
  if (!value) { event.preventDefault(); return; }
  apiKey = value;
  localStorage.setItem(KEY_ITEM, apiKey);
  connect();
});
$("key-button").addEventListener("click", () => askKey());

// -- live state ----------------------------------------------------------------------------
function connect() {
  if (events) events.close();
  if (!apiKey) { askKey(); return; }
  events = new EventSource(`/api/preflight/events?apikey=${encodeURIComponent(apiKey)}`);
  events.addEventListener("state", (e) => { setLink(true); render(JSON.parse(e.data)); });
  events.onerror = async () => {
    setLink(false);
    if (events.readyState !== EventSource.CLOSED) return;  // the browser retries by itself
    const probe = await api("/api/preflight/state").catch(() => null);
    if (!probe || probe.status !== 401) setTimeout(connect, 3000);
  };
}

function setLink(live) {
  $("link").textContent = live ? "live" : "reconnecting…";
  $("link").classList.toggle("live", live);
}

function render(state) {
  const before = lastState;
  lastState = state;
  renderPrinter(state.printer);
  renderNow(state);
  renderJobs($("queue"), state.queue, "No jobs waiting.");
  renderJobs($("history"), state.history, "No finished jobs yet.");
  const open = reportJobId();
  if (open != null) {
    const row = [...state.queue, ...state.history].find((j) => j.id === open);
    const old = before && [...before.queue, ...before.history].find((j) => j.id === open);
    if (row && (!old || old.state !== row.state || old.updated !== row.updated)) refreshReport(row);
  }
}

const STATE_TEXT = { connected: "Ready", printing: "Printing", paused: "Paused", connecting: "Connecting…",
                     waiting: "Not connected", disconnected: "Not connected", none: "No printer" };

function renderPrinter(p) {
  $("printer-state").textContent = (STATE_TEXT[p.state] || p.state || "unknown")
    + (p.message ? ` — ${p.message}` : "");
  const facts = $("printer-facts");
  facts.replaceChildren();
  const volume = p.build_volume ? p.build_volume.map((v) => +(+v).toFixed(1)).join(" × ") + " mm" : "unknown";
  const rows = [["Firmware", p.firmware || "unknown"], ["Machine", p.machine],
                ["Nozzle", p.nozzle ? `${p.nozzle} mm` + (p.nozzle_source ? ` (${p.nozzle_source})` : "") : "unknown"],
                ["Build volume", volume], ["Port", p.port]];
  for (const [k, v] of rows) if (v) facts.append(el("dt", { textContent: k }), el("dd", { textContent: v }));
  const temps = $("temperatures");
  temps.replaceChildren();
  const names = { tool0: "Nozzle", tool1: "Nozzle 2", bed: "Bed", chamber: "Chamber" };
  for (const [name, t] of Object.entries(p.temperatures || {})) {
    const target = t.target ? ` / ${Math.round(t.target)} °C` : " °C";
    temps.append(el("span", { className: "temp" }, `${names[name] || name} `,
      el("b", { textContent: t.actual == null ? "–" : (+t.actual).toFixed(1) }), target));
  }
  if (temps.childElementCount && !p.temperatures_live)
    temps.append(el("span", { className: "muted", textContent: "as read at connection" }));
}

function renderNow(state) {
  const body = $("now-body");
  const job = state.queue.find((j) => j.state === "printing" || j.state === "paused");
  if (!job) { body.replaceChildren(el("p", { className: "muted", textContent: "Nothing is printing." })); return; }
  const pct = Math.round(1000 * (job.progress || 0)) / 10;
  body.replaceChildren(
    el("p", { className: "name" }, el("strong", { textContent: job.name }), ` (job ${job.id})`),
    el("div", { className: "progress", role: "progressbar", ariaValueNow: pct }, el("div", { style: `width:${pct}%` })),
    el("p", { id: "now-progress", textContent: `${pct.toFixed(1)} % — ${duration(job.elapsed)} printing, about ${duration(job.left)} left` }),
    actionButtons(job));
}

function renderJobs(list, jobs, empty) {
  list.replaceChildren();
  if (!jobs.length) { list.append(el("li", { className: "muted", textContent: empty })); return; }
  for (const job of jobs) {
    const badge = el("span", { className: `badge ${job.state}`, textContent: job.state });
    const name = el("button", { className: "link-button name", textContent: job.name, type: "button" });
    name.addEventListener("click", () => openReport(job));
    const bits = [`#${job.id}`];
    if (job.state === "printing" || job.state === "repairing" || job.state === "slicing")
      bits.push(`${Math.round(100 * (job.progress || 0))} %`);
    if (job.state === "printing" && job.left != null) bits.push(`about ${duration(job.left)} left`);
    if (job.state === "ready" && !job.print_requested) bits.push("waiting for you to print it");
    if (job.reason) bits.push(job.reason);
    else if (job.repair) bits.push(job.repair);
    const li = el("li", { dataset: { job: job.id, state: job.state } },
      el("div", {}, name, badge), actionButtons(job), el("div", { className: "detail", textContent: bits.join(" · ") }));
    list.append(li);
  }
}

// -- actions -------------------------------------------------------------------------------
function printerPaused() {
  const p = lastState && lastState.printer;
  return Boolean(p && (p.state === "paused" || p.state === "pausing" || p.paused));
}

const ACTIONS = {
  print: { label: "Print", when: (j) => j.state === "ready" && !j.print_requested },
  pause: { label: "Pause", when: (j) => j.state === "printing" && !printerPaused(), quiet: true },
  resume: { label: "Resume", when: (j) => j.state === "paused" || (j.state === "printing" && printerPaused()), quiet: true },
  requeue: { label: "Requeue", when: (j) => ["interrupted", "failed", "cancelled"].includes(j.state), quiet: true,
             confirm: (j) => (j.state === "interrupted" || j.reached_printer) &&
               `Job ${j.id} (${j.name}) stopped part-way through its print. Clear the bed first: it will be printed again from the start. Is the bed clear?`,
             yes: "The bed is clear: print again" },
  cancel: { label: "Cancel", when: (j) => ["queued", "repairing", "slicing", "ready", "printing", "paused", "interrupted"].includes(j.state), danger: true },
};

export function actionButtons(job) {
  const box = el("div", { className: "actions" });
  for (const [action, spec] of Object.entries(ACTIONS)) {
    if (!spec.when(job)) continue;
    const b = el("button", { type: "button", textContent: spec.label,
                             className: spec.danger ? "danger" : spec.quiet ? "quiet" : "" });
    b.dataset.action = action;
    b.addEventListener("click", () => runAction(job, action, b));
    box.append(b);
  }
  return box;
}

function confirmDialog(text, yes = "Yes") {
  const dialog = $("confirm-dialog");
  $("confirm-text").textContent = text;
  $("confirm-yes").textContent = yes;
  dialog.returnValue = "";
  dialog.showModal();
  return new Promise((resolve) => dialog.addEventListener("close", () => resolve(dialog.returnValue === "yes"), { once: true }));
}

async function runAction(job, action, button) {
  const question = ACTIONS[action].confirm && ACTIONS[action].confirm(job);
  if (question && !(await confirmDialog(question, ACTIONS[action].yes))) return;
  button.disabled = true;
  try {
    const response = await api(`/api/preflight/jobs/${job.id}/${action}`, { method: "POST" });
    const answer = await response.json().catch(() => ({}));
    toast(answer.message || answer.error || `${action}: HTTP ${response.status}`, !response.ok);
  } catch (e) {
    toast(`${action} failed: ${e}`, true);
  } finally {
    button.disabled = false;
  }
}

// -- uploads -------------------------------------------------------------------------------
function upload(file) {
  const answer = $("upload-answer");
  const form = new FormData();
  const print = $("print-after").checked ? "true" : "false";
  form.append("print", print);
  form.append("select", print);
  form.append("path", "");
  form.append("file", file, file.name);
  const xhr = new XMLHttpRequest();
  xhr.open("POST", "/api/files/local");
  xhr.setRequestHeader("X-Api-Key", apiKey);
  xhr.upload.onprogress = (e) => {
    if (e.lengthComputable) answer.textContent = `Uploading ${file.name}: ${Math.round(100 * e.loaded / e.total)} %`;
  };
  xhr.onload = () => {
    let body = {};
    try { body = JSON.parse(xhr.responseText); } catch { /* not JSON */ }
    answer.classList.toggle("bad", xhr.status !== 201);
    const farm = body.preflight && body.preflight.farm;
    if (xhr.status === 201 && farm) answer.textContent = `${file.name}: ${body.preflight.message}.`;
    else if (xhr.status === 201) answer.textContent = `${file.name} is job ${body.preflight && body.preflight.job}` + (print === "true" ? ": it prints when ready." : ": it waits at ready.");
    else answer.textContent = body.error || `upload failed: HTTP ${xhr.status}`;
    if (xhr.status === 401) askKey("The key was refused: paste the current one.");
  };
  xhr.onerror = () => { answer.classList.add("bad"); answer.textContent = "upload failed: the connection dropped"; };
  answer.classList.remove("bad");
  answer.textContent = `Uploading ${file.name}…`;
  xhr.send(form);
}

const drop = $("drop");
for (const name of ["dragenter", "dragover"]) drop.addEventListener(name, (e) => { e.preventDefault(); drop.classList.add("over"); });
for (const name of ["dragleave", "drop"]) drop.addEventListener(name, () => drop.classList.remove("over"));
drop.addEventListener("drop", (e) => {
  e.preventDefault();
  for (const file of e.dataTransfer.files) upload(file);
});
$("choose-file").addEventListener("click", () => $("file-input").click());
$("file-input").addEventListener("change", (e) => { for (const file of e.target.files) upload(file); e.target.value = ""; });
$("report-close").addEventListener("click", closeReport);

connect();
