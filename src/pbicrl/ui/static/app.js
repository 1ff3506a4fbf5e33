// pbicrl label: the page. Plain JavaScript, no dependencies; talks to the JSON API of pbicrl.ui.server.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const app = {
  state: null,        // GET /api/state
  scene: null,        // GET /api/scene
  thumbs: [],         // GET /api/thumbnails: series per demonstration
  cards: [],          // card element per demonstration
  selected: null,     // selected demonstration id
  demo: null,         // GET /api/demo/{id} of the selected one
  t: 0,
  timer: null,
  suggestions: [],
  busy: false,
  polling: null,
};

// ------------------------------------------------------------------------------------------ API
async function api(method, url, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  let resp;
  try {
    resp = await fetch(url, opts);
  } catch (err) {
    throw { status: 0, message: "the pbicrl label server is not reachable (stopped?)" };
  }
  let data = null;
  try { data = await resp.json(); } catch (err) { data = null; }
  if (!resp.ok) {
    throw { status: resp.status, message: (data && data.error) || `${method} ${url}: HTTP ${resp.status}` };
  }
  return data;
}

function showError(err) {
  const banner = document.getElementById("banner");
  document.getElementById("banner-text").textContent = err.message || String(err);
  document.getElementById("banner-reload").hidden = err.status !== 409;
  banner.hidden = false;
  setStatus(err.status === 409 ? "conflict: reload" : "not saved", "bad");
}

function setStatus(text, kind) {
  const el = document.getElementById("status");
  el.textContent = text;
  el.className = "pill" + (kind ? " " + kind : "");
}

// Every change sends the revision the page last saw; the server answers with the new state (or 409).
async function change(url, body) {
  if (app.busy) return;
  app.busy = true;
  setStatus("saving…", "busy");
  try {
    const st = await api("POST", url, Object.assign({ revision: app.state.revision }, body));
    applyState(st);
  } catch (err) {
    showError(err);
  } finally {
    app.busy = false;
  }
}

function applyState(st) {
  app.state = st;
  const base = (p) => p.split(/[\\/]/).pop();
  const files = document.getElementById("files");
  files.textContent = `${base(st.source)} → ${base(st.out)}`;
  files.title = `${st.source} → ${st.out} (saved on every change)`;
  if (st.saved_revision === st.revision) setStatus(`saved · revision ${st.revision}`);
  else setStatus(`revision ${st.revision} · nothing changed yet`);
  renderBoard();
}

// ------------------------------------------------------------------------------------------ drawing
function el(tag, attrs, parent) {
  const e = document.createElementNS(SVG, tag);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (parent) parent.appendChild(e);
  return e;
}

// Draws series (rows of numbers, one per time step) into svg (w x h); upto = last step shown, or -1 for all.
function drawSeries(svg, series, w, h, upto, big) {
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  const sc = app.scene;
  if (!sc || !series || !series.length) return;
  const n = series.length;
  const last = upto < 0 ? n - 1 : Math.min(upto, n - 1);
  const lw = big ? 2.5 : 1.5;
  if (sc.kind === "navigation" || sc.kind === "path2d") {
    const [x0, x1, y0, y1] = sc.bounds;
    const s = Math.min(w / (x1 - x0), h / (y1 - y0));
    const ox = (w - s * (x1 - x0)) / 2, oy = (h - s * (y1 - y0)) / 2;
    const X = (x) => ox + s * (x - x0), Y = (y) => h - oy - s * (y - y0);
    el("rect", { x: X(x0), y: Y(y1), width: s * (x1 - x0), height: s * (y1 - y0), fill: "#fbfbfb", stroke: "#eee" }, svg);
    for (const r of sc.regions) {
      if (r.shape === "disc") {
        el("circle", { cx: X(r.centre[0]), cy: Y(r.centre[1]), r: s * r.radius, fill: r.color, "fill-opacity": 0.35, stroke: r.color }, svg);
      } else {
        el("rect", { x: X(r.low[0]), y: Y(r.high[1]), width: s * (r.high[0] - r.low[0]), height: s * (r.high[1] - r.low[1]),
                     fill: r.color, "fill-opacity": 0.35, stroke: r.color }, svg);
      }
      if (big) el("text", { x: X(r.shape === "disc" ? r.centre[0] : (r.low[0] + r.high[0]) / 2),
                            y: Y(r.shape === "disc" ? r.centre[1] : (r.low[1] + r.high[1]) / 2),
                            "text-anchor": "middle", "font-size": 12, fill: "#555" }, svg).textContent = r.name;
    }
    const pts = (a, b) => series.slice(a, b + 1).map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" ");
    el("polyline", { points: pts(0, n - 1), fill: "none", stroke: "#90a4ae", "stroke-width": lw * 0.6 }, svg);
    el("polyline", { points: pts(0, last), fill: "none", stroke: "#1565c0", "stroke-width": lw }, svg);
    el("circle", { cx: X(series[0][0]), cy: Y(series[0][1]), r: big ? 4 : 2, fill: "#333" }, svg);
    el("circle", { cx: X(series[last][0]), cy: Y(series[last][1]), r: big ? 6 : 2.5, fill: "#1565c0", stroke: "#fff" }, svg);
  } else if (sc.kind === "grid") {
    const R = sc.rows, C = sc.cols, cw = w / C, ch = h / R;
    for (let r = 0; r < R; r++) for (let c = 0; c < C; c++) {
      el("rect", { x: c * cw, y: (R - 1 - r) * ch, width: cw, height: ch, fill: sc.cells[r][c].color, "fill-opacity": 0.6, stroke: "#fff" }, svg);
    }
    const P = (p) => `${((p[1] + 0.5) * cw).toFixed(1)},${((R - 0.5 - p[0]) * ch).toFixed(1)}`;
    el("polyline", { points: series.map(P).join(" "), fill: "none", stroke: "#90a4ae", "stroke-width": lw }, svg);
    el("polyline", { points: series.slice(0, last + 1).map(P).join(" "), fill: "none", stroke: "#1565c0", "stroke-width": lw * 1.5 }, svg);
    const q = series[last];
    el("circle", { cx: (q[1] + 0.5) * cw, cy: (R - 0.5 - q[0]) * ch, r: big ? 8 : 3, fill: "#1565c0" }, svg);
  } else if (sc.kind === "wall") {
    const [lo, hi] = sc.x_range, T = Math.max(sc.max_length - 1, 1);
    const X = (t) => 4 + (w - 8) * (t / T), Y = (x) => h - 4 - (h - 8) * ((x - lo) / (hi - lo || 1));
    if (sc.wall_x !== null) {
      el("rect", { x: 0, y: 0, width: w, height: Y(sc.wall_x), fill: "#c0392b", "fill-opacity": 0.12 }, svg);
      el("line", { x1: 0, x2: w, y1: Y(sc.wall_x), y2: Y(sc.wall_x), stroke: "#c0392b", "stroke-dasharray": "4 3" }, svg);
      if (big) el("text", { x: 6, y: Y(sc.wall_x) - 4, "font-size": 12, fill: "#c0392b" }, svg).textContent = `wall x = ${sc.wall_x}`;
    }
    // thumbnails are thinned: their index runs over the whole trajectory
    const tOf = (i) => (app.thumbsFull ? i : i * ((seriesLength(series) - 1) / Math.max(n - 1, 1)));
    const pts = (b) => series.slice(0, b + 1).map((p, i) => `${X(tOf(i)).toFixed(1)},${Y(p[0]).toFixed(1)}`).join(" ");
    el("polyline", { points: pts(n - 1), fill: "none", stroke: "#90a4ae", "stroke-width": lw * 0.6 }, svg);
    el("polyline", { points: pts(last), fill: "none", stroke: "#1565c0", "stroke-width": lw }, svg);
    el("circle", { cx: X(tOf(last)), cy: Y(series[last][0]), r: big ? 5 : 2, fill: "#1565c0" }, svg);
    if (big) el("text", { x: w - 4, y: h - 6, "text-anchor": "end", "font-size": 11, fill: "#777" }, svg).textContent = "x(t)";
  } else {  // features: one strip per feature over time
    const d = sc.feature_names.length, T = Math.max(sc.max_length - 1, 1), sh = h / d;
    for (let j = 0; j < d; j++) {
      const [lo, hi] = sc.ranges[j];
      const Y = (v) => (j + 1) * sh - 2 - (sh - 4) * ((v - lo) / (hi - lo || 1));
      const tOf = (i) => (app.thumbsFull ? i : i * ((seriesLength(series) - 1) / Math.max(n - 1, 1)));
      const X = (i) => 2 + (w - 4) * (tOf(i) / T);
      el("rect", { x: 0, y: j * sh, width: w, height: sh, fill: j % 2 ? "#fafafa" : "#f2f6fb" }, svg);
      el("polyline", { points: series.slice(0, last + 1).map((p, i) => `${X(i).toFixed(1)},${Y(p[j]).toFixed(1)}`).join(" "),
                       fill: "none", stroke: "#1565c0", "stroke-width": big ? 1.5 : 1 }, svg);
      if (big) el("text", { x: 4, y: j * sh + 12, "font-size": 11, fill: "#555" }, svg).textContent = sc.feature_names[j];
    }
  }
}

// The real length of a thinned series: the thumbnails keep both ends, the lengths come with the state.
function seriesLength(series) { return series._length || series.length; }

function drawBig() {
  const svg = document.getElementById("big");
  if (!app.demo) { while (svg.firstChild) svg.removeChild(svg.firstChild); return; }
  app.thumbsFull = true;
  drawSeries(svg, app.demo.series, 400, app.scene.kind === "navigation" || app.scene.kind === "grid" || app.scene.kind === "path2d" ? 400 : 260, app.t, true);
  app.thumbsFull = false;
  document.getElementById("tlabel").textContent = `t = ${app.t} / ${app.demo.length - 1}`;
}

// ------------------------------------------------------------------------------------------ board
function makeCard(i) {
  const card = document.createElement("div");
  card.className = "card";
  card.draggable = true;
  card.tabIndex = -1;
  card.dataset.id = i;
  card.id = `card-${i}`;
  const svg = document.createElementNS(SVG, "svg");
  const series = app.thumbs[i];
  series._length = app.state.lengths[i];
  drawSeries(svg, series, 70, 52, -1, false);
  card.appendChild(svg);
  const label = document.createElement("div");
  label.textContent = `#${i}`;
  card.appendChild(label);
  card.addEventListener("click", () => select(i));
  card.addEventListener("dragstart", (e) => {
    e.dataTransfer.setData("text/plain", String(i));
    e.dataTransfer.effectAllowed = "move";
  });
  return card;
}

function dropZone(zone) {
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    const id = parseInt(e.dataTransfer.getData("text/plain"), 10);
    if (Number.isNaN(id)) return;
    const g = zone.dataset.group;
    if (g === "skip") change("/api/skip", { ids: [id], skipped: true });
    else change("/api/assign", { ids: [id], group: parseInt(g, 10) });
    select(id);
  });
}

function groupOps(k) {
  const st = app.state, names = st.groups.map((g) => g.name), source = names.map((_, i) => i + 1);
  return { names, source, K: names.length, k };
}

function renderBoard() {
  const st = app.state;
  const box = document.getElementById("groups");
  box.textContent = "";
  const holders = { 0: document.getElementById("pool"), skip: document.getElementById("skipped") };
  st.groups.forEach((g, idx) => {
    const zone = document.createElement("div");
    zone.className = "zone group";
    zone.dataset.group = g.label;
    zone.id = `group-${g.label}`;
    const head = document.createElement("div");
    head.className = "head";
    const rank = document.createElement("span");
    rank.className = "rank";
    rank.textContent = g.label;
    rank.title = `key ${g.label <= 9 ? g.label : "-"}`;
    const name = document.createElement("input");
    name.className = "name";
    name.value = g.name;
    name.setAttribute("aria-label", `name of group ${g.label}`);
    name.addEventListener("change", () => {
      const o = groupOps(idx);
      o.names[idx] = name.value;
      change("/api/groups", { names: o.names, source: o.source });
    });
    const count = document.createElement("span");
    count.className = "muted small";
    count.textContent = `(${g.count})`;
    const left = button("←", `move group ${g.label} up the ranking`, idx === 0, () => swap(idx, idx - 1));
    const right = button("→", `move group ${g.label} down the ranking`, idx === st.groups.length - 1, () => swap(idx, idx + 1));
    const del = button("×", `delete group ${g.label} (its demonstrations become unlabelled)`, false, () => {
      if (g.count && !confirm(`Delete group "${g.name}"? Its ${g.count} demonstrations become unlabelled.`)) return;
      const o = groupOps(idx);
      o.names.splice(idx, 1);
      o.source.splice(idx, 1);
      if (!o.names.length) { showError({ message: "keep at least one group" }); return; }
      change("/api/groups", { names: o.names, source: o.source });
    });
    head.append(rank, name, count, left, right, del);
    const cards = document.createElement("div");
    cards.className = "cards";
    zone.append(head, cards);
    dropZone(zone);
    box.appendChild(zone);
    holders[g.label] = cards;
  });
  holders[0].textContent = "";
  holders.skip.textContent = "";
  // suggested demonstrations first in the pool, in their order
  const order = [...app.suggestions.filter((i) => st.group[i] === 0 && !st.skipped[i]),
                 ...st.group.map((_, i) => i).filter((i) => !app.suggestions.includes(i))];
  for (const i of order) {
    const card = app.cards[i];
    card.classList.toggle("skip", st.skipped[i]);
    card.classList.toggle("suggested", app.suggestions.includes(i) && st.group[i] === 0);
    const where = st.skipped[i] ? holders.skip : holders[st.group[i]] || holders[0];
    where.appendChild(card);
  }
  document.getElementById("pool-count").textContent = `(${st.n_unlabelled})`;
  document.getElementById("skip-count").textContent = `(${st.n_skipped})`;
  renderGaps();
  if (app.selected !== null) app.cards[app.selected].classList.add("selected");
  renderInfo();
}

function button(text, title, disabled, onclick) {
  const b = document.createElement("button");
  b.textContent = text;
  b.title = title;
  b.disabled = disabled;
  b.addEventListener("click", onclick);
  return b;
}

function swap(a, b) {
  const o = groupOps(a);
  [o.names[a], o.names[b]] = [o.names[b], o.names[a]];
  [o.source[a], o.source[b]] = [o.source[b], o.source[a]];
  change("/api/groups", { names: o.names, source: o.source });
}

function renderGaps() {
  const st = app.state, box = document.getElementById("gaps");
  box.textContent = "";
  if (st.groups.length < 2) return;
  const lab = document.createElement("span");
  lab.textContent = "Gap relation (relative sizes; for tune-margins --relation):";
  box.appendChild(lab);
  const inputs = [];
  for (let k = 0; k + 1 < st.groups.length; k++) {
    const l = document.createElement("label");
    l.textContent = `${st.groups[k].name} – ${st.groups[k + 1].name} `;
    const inp = document.createElement("input");
    inp.type = "number";
    inp.min = "0";
    inp.step = "any";
    inp.className = "gap";
    inp.value = st.gap_relation ? st.gap_relation[k] : "";
    inp.placeholder = "?";
    l.appendChild(inp);
    box.appendChild(l);
    inputs.push(inp);
  }
  const save = button("Save gaps", "store the gap relation with the labels", false, () => {
    const vals = inputs.map((i) => parseFloat(i.value));
    if (vals.some((v) => !(v > 0))) { showError({ message: "gap relation: give a positive number for every gap" }); return; }
    change("/api/gaps", { gap_relation: vals });
  });
  const clear = button("Clear", "no gap relation", st.gap_relation === null, () => change("/api/gaps", { gap_relation: null }));
  save.id = "save-gaps";
  box.append(save, clear);
}

function renderInfo() {
  const info = document.getElementById("demo-info");
  const i = app.selected;
  if (i === null || !app.demo) { info.textContent = ""; return; }
  const st = app.state;
  const where = st.skipped[i] ? "skipped" : st.group[i] ? `group ${st.group[i]} (${st.groups[st.group[i] - 1].name})` : "unlabelled";
  const feats = app.demo.feature_names.map((n, j) => `${n} ${app.demo.mean_features[j].toPrecision(3)}`).join(" · ");
  info.textContent = `#${i}: ${app.demo.length} steps, ${where}. Mean features: ${feats}`;
}

// ------------------------------------------------------------------------------------------ selection, playback
async function select(i) {
  if (i === null || i < 0 || i >= app.state.n) return;
  if (app.selected !== null) app.cards[app.selected].classList.remove("selected");
  app.selected = i;
  const card = app.cards[i];
  card.classList.add("selected");
  card.scrollIntoView({ block: "nearest", inline: "nearest" });
  document.getElementById("demo-title").textContent = `#${i}`;
  try {
    const demo = await api("GET", `/api/demo/${i}`);
    if (app.selected !== i) return;
    app.demo = demo;
    app.t = demo.length - 1;
    const scrub = document.getElementById("scrub");
    scrub.max = demo.length - 1;
    scrub.value = app.t;
    stop();
    drawBig();
    renderInfo();
  } catch (err) { showError(err); }
}

function stop() {
  if (app.timer) clearInterval(app.timer);
  app.timer = null;
  document.getElementById("play").textContent = "▶";
}

function play() {
  if (!app.demo) return;
  if (app.timer) { stop(); return; }
  const T = app.demo.length;
  const step = Math.max(1, Math.round(T / 90));
  if (app.t >= T - 1) app.t = 0;
  document.getElementById("play").textContent = "❚❚";
  app.timer = setInterval(() => {
    app.t = Math.min(app.t + step, T - 1);
    document.getElementById("scrub").value = app.t;
    drawBig();
    if (app.t >= T - 1) stop();
  }, 33);
}

function visibleOrder() {
  return [...document.querySelectorAll(".card")].map((c) => parseInt(c.dataset.id, 10));
}

function nextUnlabelled(after) {
  const order = visibleOrder(), st = app.state;
  const start = order.indexOf(after);
  for (let k = 1; k <= order.length; k++) {
    const i = order[(start + k) % order.length];
    if (st.group[i] === 0 && !st.skipped[i]) return i;
  }
  return after;
}

function onKey(e) {
  if (e.target.tagName === "INPUT" || e.ctrlKey || e.metaKey || e.altKey) return;
  const st = app.state, i = app.selected;
  if (e.key === " ") { e.preventDefault(); play(); return; }
  if (["ArrowRight", "ArrowDown", "ArrowLeft", "ArrowUp"].includes(e.key)) {
    e.preventDefault();
    const order = visibleOrder();
    const pos = i === null ? -1 : order.indexOf(i);
    const d = e.key === "ArrowRight" || e.key === "ArrowDown" ? 1 : -1;
    select(order[(pos + d + order.length) % order.length]);
    return;
  }
  if (i === null) return;
  if (/^[0-9]$/.test(e.key)) {
    const g = parseInt(e.key, 10);
    if (g > st.groups.length) { showError({ message: `no group ${g}: there are ${st.groups.length}` }); return; }
    const next = g > 0 ? nextUnlabelled(i) : i;
    change("/api/assign", { ids: [i], group: g }).then(() => { if (next !== i) select(next); });
  } else if (e.key === "s") {
    const next = nextUnlabelled(i);
    change("/api/skip", { ids: [i], skipped: !st.skipped[i] }).then(() => { if (!st.skipped[i] && next !== i) select(next); });
  }
}

// ------------------------------------------------------------------------------------------ inference
async function runInference() {
  const body = {
    iterations: parseInt(document.getElementById("iterations").value, 10),
    chains: parseInt(document.getElementById("chains").value, 10),
    figures: document.getElementById("figures").checked,
  };
  const m = document.getElementById("margins").value.trim();
  if (m) {
    body.margins = m.split(",").map((x) => parseFloat(x));
    if (body.margins.some((x) => Number.isNaN(x))) { showError({ message: "margins: give numbers such as 0,2.9" }); return; }
  }
  try {
    await api("POST", "/api/infer", body);
    document.getElementById("infer-btn").disabled = true;
    poll();
  } catch (err) { showError(err); }
}

function poll() {
  if (app.polling) clearTimeout(app.polling);
  api("GET", "/api/infer").then((job) => {
    const bar = document.getElementById("progress");
    bar.hidden = job.status === "idle";
    document.getElementById("progress-bar").style.width = `${Math.round(100 * job.progress)}%`;
    document.getElementById("progress-text").textContent =
      job.status === "running" ? `${job.phase} ${Math.round(100 * job.progress)}% · ${job.elapsed_s ?? 0} s` :
      job.status === "error" ? `failed: ${job.message}` : job.status === "done" ? `done in ${job.elapsed_s} s` : "";
    if (job.status === "running") { app.polling = setTimeout(poll, 500); return; }
    document.getElementById("infer-btn").disabled = false;
    if (job.status === "error") showError({ message: job.message });
    if (job.status === "done") renderResult(job.result, job.revision);
  }).catch(showError);
}

function fmt(x) { return x === null || x === undefined ? "–" : Math.abs(x) >= 100 ? x.toFixed(0) : x.toPrecision(3); }

function renderResult(res, revision) {
  const out = document.getElementById("infer-out");
  out.textContent = "";
  const p = document.createElement("p");
  p.className = "small";
  // P(c=1) and a selection only where they are posterior probabilities (res.indicator_meaning "posterior");
  // a chain frequency (paper/authors samplers) or bpl's model membership is shown under its own name
  const meaning = res.indicator_meaning || "posterior";
  if (res.selected === null || res.selected === undefined) {
    p.textContent = `Labels of revision ${revision}; ${res.n_draws} draws. No selection: the column "${res.indicator_label}" is not a posterior probability.`;
  } else {
    p.innerHTML = `Labels of revision ${revision}; ${res.n_draws} draws. Selected: <b></b>`;
    p.querySelector("b").textContent = res.selected.length ? res.selected.join(", ") : "none";
  }
  out.appendChild(p);
  const t = document.createElement("table");
  t.id = "posterior-table";
  const second = { posterior: "sel.", chain_frequency: "MAP", fixed: "" }[meaning];
  t.innerHTML = "<thead><tr><th>feature</th><th></th><th></th><th>median w_p | c=1</th><th>90% interval</th></tr></thead>";
  t.querySelectorAll("th")[1].textContent = meaning === "posterior" ? "P(c=1)" : res.indicator_label;
  t.querySelectorAll("th")[2].textContent = second;
  const tb = document.createElement("tbody");
  for (const f of res.features) {
    const tr = document.createElement("tr");
    const mark = meaning === "posterior" ? (f.selected ? "✓" : "") : meaning === "chain_frequency" ? (f.map_indicator ? "on" : "off") : "";
    const cells = [f.name, null, mark, fmt(f.median), f.low === null ? "–" : `[${fmt(f.low)}, ${fmt(f.high)}]`];
    cells.forEach((c, j) => {
      const td = document.createElement("td");
      if (j === 1) {
        if (meaning === "fixed") { td.textContent = f.in_model ? "yes" : "no"; tr.appendChild(td); return; }
        const v = meaning === "posterior" ? f.p_constraint : f.frequency_on;
        const bar = document.createElement("span");
        bar.className = "pbar";
        bar.style.width = `${Math.round(50 * v)}px`;
        td.append(bar, document.createTextNode(v.toFixed(3)));
      } else td.textContent = c;
      tr.appendChild(td);
    });
    tb.appendChild(tr);
  }
  t.appendChild(tb);
  out.appendChild(t);
  out.appendChild(rewardPlot(res.groups));
  if ((res.warnings || []).length) {
    const det = document.createElement("details");
    det.className = "small muted";
    const sum = document.createElement("summary");
    sum.textContent = `${res.warnings.length} warning(s) about this run`;
    det.appendChild(sum);
    for (const w of res.warnings) {
      const d = document.createElement("p");
      d.textContent = w;
      det.appendChild(d);
    }
    out.appendChild(det);
  }
  if (res.suggestions) {
    app.suggestions = res.suggestions.suggestions.map((s) => s.index);
    const h = document.createElement("h3");
    h.textContent = "Label these next (most informative about the constraints)";
    const ul = document.createElement("ol");
    ul.className = "sugg small";
    for (const s of res.suggestions.suggestions) {
      const li = document.createElement("li");
      const probs = Object.entries(s.group_probabilities).map(([g, v]) => `${g} ${v.toFixed(2)}`).join(", ");
      li.textContent = `#${s.index}: ${s.information_gain.toFixed(3)} nats (predicted: ${probs})`;
      li.addEventListener("click", () => select(s.index));
      ul.appendChild(li);
    }
    out.append(h, ul);
    document.getElementById("next-btn").disabled = false;
    renderBoard();
  } else if (res.suggestions_note) {
    const d = document.createElement("div");
    d.className = "small muted";
    d.textContent = res.suggestions_note;
    out.appendChild(d);
  }
  for (const name of res.figures || []) {
    const img = document.createElement("img");
    img.src = `/api/figures/${name}?r=${revision}-${Date.now()}`;
    img.alt = name;
    out.appendChild(img);
  }
  if (res.figures_note) {
    const d = document.createElement("div");
    d.className = "small muted";
    d.textContent = res.figures_note;
    out.appendChild(d);
  }
  const d = document.createElement("div");
  d.className = "small muted";
  d.textContent = `run saved in ${res.run_dir}`;
  out.appendChild(d);
}

// Box plot of each group's returns under the selected-set estimate (min, 10/25/50/75/90 %, max).
function rewardPlot(groups) {
  const w = 340, rowh = 26, h = 24 + rowh * groups.length;
  const svg = document.createElementNS(SVG, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  svg.setAttribute("width", "100%");
  svg.id = "reward-plot";
  const lo = Math.min(...groups.map((g) => g.quantiles[0])), hi = Math.max(...groups.map((g) => g.quantiles[6]));
  const X = (v) => 90 + (w - 100) * ((v - lo) / (hi - lo || 1));
  el("text", { x: 4, y: 14, "font-size": 11, fill: "#555" }, svg).textContent = "reward per group (selected-set estimate)";
  groups.forEach((g, k) => {
    const y = 30 + k * rowh, q = g.quantiles;
    el("text", { x: 4, y: y + 4, "font-size": 11 }, svg).textContent = `${g.name} (${g.n})`;
    el("line", { x1: X(q[0]), x2: X(q[6]), y1: y, y2: y, stroke: "#999" }, svg);
    el("rect", { x: X(q[1]), y: y - 5, width: Math.max(X(q[5]) - X(q[1]), 1), height: 10, fill: "#bbdefb" }, svg);
    el("rect", { x: X(q[2]), y: y - 7, width: Math.max(X(q[4]) - X(q[2]), 1), height: 14, fill: "#64b5f6" }, svg);
    el("line", { x1: X(q[3]), x2: X(q[3]), y1: y - 8, y2: y + 8, stroke: "#0d47a1", "stroke-width": 2 }, svg);
  });
  return svg;
}

// ------------------------------------------------------------------------------------------ start
async function main() {
  try {
    const [st, scene, thumbs] = await Promise.all([api("GET", "/api/state"), api("GET", "/api/scene"), api("GET", "/api/thumbnails")]);
    app.scene = scene;
    app.thumbs = thumbs.series;
    app.state = st;
    app.cards = app.thumbs.map((_, i) => makeCard(i));
    document.getElementById("scene-note").textContent = [scene.projection ? `view: ${scene.projection}` : "", scene.note || ""].filter(Boolean).join(" · ");
    dropZone(document.getElementById("pool-zone"));
    dropZone(document.getElementById("skip-zone"));
    applyState(st);
    const first = st.group.findIndex((g, i) => g === 0 && !st.skipped[i]);
    select(first >= 0 ? first : 0);
    poll();
  } catch (err) { showError(err); }
  document.addEventListener("keydown", onKey);
  document.getElementById("play").addEventListener("click", play);
  document.getElementById("scrub").addEventListener("input", (e) => { stop(); app.t = parseInt(e.target.value, 10); drawBig(); });
  document.getElementById("add-group").addEventListener("click", () => {
    const o = groupOps(0);
    let k = o.K + 1, name = `group ${k}`;
    while (o.names.includes(name)) name = `group ${++k}`;
    change("/api/groups", { names: [...o.names, name], source: [...o.source, null] });
  });
  document.getElementById("infer-btn").addEventListener("click", runInference);
  document.getElementById("next-btn").addEventListener("click", () => {
    const todo = app.suggestions.filter((i) => app.state.group[i] === 0 && !app.state.skipped[i]);
    renderBoard();
    if (todo.length) select(todo[0]);
  });
  document.getElementById("banner-close").addEventListener("click", () => { document.getElementById("banner").hidden = true; });
  document.getElementById("banner-reload").addEventListener("click", () => location.reload());
}

main();
