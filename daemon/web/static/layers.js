// The G-code layer by layer on a 2D canvas: the chosen layer in colour (by the slicer's
// ;TYPE: where it writes them), the one below it faint; a slider picks the layer.
const PALETTE = ["#f59e0b", "#38bdf8", "#a3e635", "#f472b6", "#c084fc", "#fb923c", "#2dd4bf",
                 "#facc15", "#60a5fa", "#e879f9", "#4ade80", "#f87171"];
const WINDOW = 20;  // layers fetched at a time

export class LayerPreview {
  constructor(canvas, slider, label, legend, api) {
    Object.assign(this, { canvas, slider, label, legend, api });
    this.cache = new Map();
    this.info = null;
    slider.addEventListener("input", () => this.draw(+slider.value));
    new ResizeObserver(() => this.info && this.draw(+slider.value)).observe(canvas);
  }

  async fetchWindow(index) {
    const first = Math.floor(index / WINDOW) * WINDOW;
    const r = await this.api(`/api/preflight/jobs/${this.job}/layers?from=${first}&count=${WINDOW}`);
    if (!r.ok) throw new Error((await r.json().catch(() => ({}))).error || `HTTP ${r.status}`);
    const data = await r.json();
    for (const layer of data.layers) this.cache.set(layer.index, layer);
    return data;
  }

  async layer(index) {
    if (!this.cache.has(index)) await this.fetchWindow(index);
    return this.cache.get(index);
  }

  async load(job) {
    this.job = job;
    this.cache.clear();
    try {
      this.info = await this.fetchWindow(0);
    } catch (e) {
      this.label.textContent = `no preview: ${e.message || e}`;
      return;
    }
    this.slider.max = Math.max(this.info.count - 1, 0);
    const start = Math.min(Math.floor(this.info.count / 2), this.info.count - 1);
    this.slider.value = Math.max(start, 0);
    this.legend.replaceChildren(...this.info.types.map((t, i) => {
      const span = document.createElement("span");
      span.style.setProperty("--swatch", PALETTE[i % PALETTE.length]);
      span.textContent = t;
      return span;
    }));
    await this.draw(+this.slider.value);
  }

  async draw(index) {
    if (!this.info || !this.info.count) { this.label.textContent = "no extruding moves"; return; }
    this.drawing = index;
    const [layer, below] = await Promise.all([this.layer(index), index > 0 ? this.layer(index - 1) : null]);
    if (this.drawing !== index) return;  // the slider moved on meanwhile
    const c = this.canvas, ctx = c.getContext("2d");
    const size = Math.round(c.clientWidth * (window.devicePixelRatio || 1)) || 600;
    if (c.width !== size) { c.width = size; c.height = size; }
    const [x0, y0, x1, y1] = this.info.bounds;
    const span = Math.max(x1 - x0, y1 - y0, 1e-3), margin = size * 0.06;
    const scale = (size - 2 * margin) / span;
    const ox = margin + ((size - 2 * margin) - (x1 - x0) * scale) / 2;
    const oy = margin + ((size - 2 * margin) - (y1 - y0) * scale) / 2;
    const X = (x) => ox + (x - x0) * scale, Y = (y) => size - (oy + (y - y0) * scale);
    ctx.fillStyle = "#1f2533";
    ctx.fillRect(0, 0, size, size);
    ctx.lineCap = ctx.lineJoin = "round";
    const stroke = (paths, style) => {
      for (const path of paths) {
        ctx.strokeStyle = style || PALETTE[path[0] % PALETTE.length];
        ctx.beginPath();
        ctx.moveTo(X(path[1]), Y(path[2]));
        for (let k = 3; k < path.length; k += 2) ctx.lineTo(X(path[k]), Y(path[k + 1]));
        ctx.stroke();
      }
    };
    ctx.lineWidth = Math.max(1, 0.4 * scale);
    if (below) stroke(below.paths, "rgba(200, 210, 230, 0.18)");
    stroke(layer.paths);
    this.label.textContent = `layer ${index + 1} of ${this.info.count}, z ${layer.z} mm`;
  }
}
