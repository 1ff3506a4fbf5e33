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
  multi: new Set(),   // shift-click selection: the keys and a drag apply to all of them
  undo: [],           // label changes to undo (Ctrl-Z), each {ids, group, skipped} as they were before
  toastTimer: null,
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

// Errors appear in a toast fixed in the viewport (where the user is looking, however far the page is scrolled).
function showError(err, opts) {
  const banner = document.getElementById("banner");
  document.getElementById("banner-text").textContent = err.message || String(err);
  document.getElementById("banner-reload").hidden = err.status !== 409;
  banner.hidden = false;
  if (app.toastTimer) clearTimeout(app.toastTimer);
  // a conflict stays until the user reloads or closes it; anything else fades after a while
  if (err.status !== 409) app.toastTimer = setTimeout(() => { banner.hidden = true; }, 8000);
  if (!(opts && opts.keepStatus)) setStatus(err.status === 409 ? "conflict: reload" : "not saved", "bad");
}

function setStatus(text, kind) {
  const el = document.getElementById("status");
  el.textContent = text;
  el.className = "pill" + (kind ? " " + kind : "");
}

// Every change sends the revision the page last saw; the server answers with the new state (or 409).
async function change(url, body, opts) {
  if (app.busy) return false;
  app.busy = true;
  setStatus("saving…", "busy");
  const before = app.state;
  try {
    const st = await api("POST", url, Object.assign({ revision: app.state.revision }, body));
    if (url === "/api/assign" || url === "/api/skip") {
      if (!(opts && opts.undoing)) {
        app.undo.push(body.ids.map((i) => ({ id: i, group: before.group[i], skipped: before.skipped[i] })));
        if (app.undo.length > 100) app.undo.shift();
      }
    } else if (url === "/api/groups") {
      app.undo = [];  // group labels changed meaning: an older label change cannot be undone safely
    }
    applyState(st);
    return true;
  } catch (err) {
    showError(err);
    return false;
  } finally {
    app.busy = false;
  }
}

// Ctrl-Z: put the demonstrations of the last label change back where they were.
async function undoLast() {
  const last = app.undo.pop();
  if (!last) { showError({ message: "nothing to undo" }, { keepStatus: true }); return; }
  const skipped = last.filter((e) => e.skipped).map((e) => e.id);
  const byGroup = new Map();
  for (const e of last) if (!e.skipped) byGroup.set(e.group, [...(byGroup.get(e.group) || []), e.id]);
  if (skipped.length) await change("/api/skip", { ids: skipped, skipped: true }, { undoing: true });
  for (const [g, ids] of byGroup) await change("/api/assign", { ids, group: g }, { undoing: true });
  setStatus(`undone · revision ${app.state.revision}`);
}

function targets() {
  return app.multi.size ? [...app.multi] : app.selected === null ? [] : [app.selected];
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
  // the large view keeps a margin for its axes (ticks with values and axis names)
  const L = big ? 44 : 0, B = big ? 34 : 0, T0 = big ? 6 : 0, R0 = big ? 8 : 0;
  const pw = w - L - R0, ph = h - T0 - B;
  if (sc.kind === "navigation" || sc.kind === "path2d") {
    const [x0, x1, y0, y1] = sc.bounds;
    const s = Math.min(pw / (x1 - x0), ph / (y1 - y0));
    const ox = L + (pw - s * (x1 - x0)) / 2, oy = B + (ph - s * (y1 - y0)) / 2;
    const X = (x) => ox + s * (x - x0), Y = (y) => h - oy - s * (y - y0);
    el("rect", { x: X(x0), y: Y(y1), width: s * (x1 - x0), height: s * (y1 - y0), fill: "#fbfbfb", stroke: "#eee" }, svg);
    if (big) {
      const names = sc.axis_labels || ["x", "y"];
      axis(svg, "x", ticks(x0, x1, 5), X, Y(y0), names[0], (X(x0) + X(x1)) / 2, h - 4);
      axis(svg, "y", ticks(y0, y1, 5), Y, X(x0), names[1], 12, (Y(y0) + Y(y1)) / 2);
    }
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
    let [lo, hi] = sc.x_range;
    if (big) {  // the large view zooms to this demonstration and the wall: x = 7.9 and 8.1 must look different
      const xs = series.map((p) => p[0]).concat(sc.wall_x === null ? [] : [sc.wall_x]);
      const a = Math.min(...xs), b = Math.max(...xs), pad = 0.06 * (b - a || 1);
      [lo, hi] = [a - pad, b + pad];
    }
    const T = Math.max(sc.max_length - 1, 1);
    const X = (t) => L + 4 + (pw - 8) * (t / T), Y = (x) => h - B - 4 - (ph - 8) * ((x - lo) / (hi - lo || 1));
    if (big) {
      axis(svg, "x", ticks(0, T, 5), X, h - B, "time step t", L + pw / 2, h - 4);
      axis(svg, "y", ticks(lo, hi, 8), Y, L, "x (forward position)", 12, T0 + ph / 2);
    }
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
  } else {  // features: one strip per feature over time
    const d = sc.feature_names.length, T = Math.max(sc.max_length - 1, 1), sh = ph / d;
    const tOf = (i) => (app.thumbsFull ? i : i * ((seriesLength(series) - 1) / Math.max(n - 1, 1)));
    const Xt = (t) => L + 2 + (pw - 4) * (t / T);
    for (let j = 0; j < d; j++) {
      const [lo, hi] = sc.ranges[j];
      const Y = (v) => T0 + (j + 1) * sh - 2 - (sh - 4) * ((v - lo) / (hi - lo || 1));
      el("rect", { x: L, y: T0 + j * sh, width: pw, height: sh, fill: j % 2 ? "#fafafa" : "#f2f6fb" }, svg);
      el("polyline", { points: series.slice(0, last + 1).map((p, i) => `${Xt(tOf(i)).toFixed(1)},${Y(p[j]).toFixed(1)}`).join(" "),
                       fill: "none", stroke: "#1565c0", "stroke-width": big ? 1.5 : 1 }, svg);
      if (big) {
        el("text", { x: L + 4, y: T0 + j * sh + 12, "font-size": 11, fill: "#555" }, svg).textContent = sc.feature_names[j];
        for (const v of [lo, hi]) {
          el("text", { x: L - 3, y: Y(v) + 3, "font-size": 9, "text-anchor": "end", fill: "#333", class: "tick-label" }, svg).textContent = tickText(v);
        }
      }
    }
    if (big) axis(svg, "x", ticks(0, T, 5), Xt, h - B, "time step t", L + pw / 2, h - 4);
  }
}

// An axis of the large view: a line, ticks with their values and the axis name.
function axis(svg, which, values, at, pos, name, nx, ny) {
  const g = el("g", { class: `axis axis-${which}` }, svg);
  for (const v of values) {
    const p = at(v);
    if (which === "x") {
      el("line", { x1: p, x2: p, y1: pos, y2: pos + 4, stroke: "#555" }, g);
      el("text", { x: p, y: pos + 14, "font-size": 10, "text-anchor": "middle", fill: "#333", class: "tick-label" }, g).textContent = tickText(v);
    } else {
      el("line", { x1: pos - 4, x2: pos, y1: p, y2: p, stroke: "#555" }, g);
      el("text", { x: pos - 6, y: p + 3, "font-size": 10, "text-anchor": "end", fill: "#333", class: "tick-label" }, g).textContent = tickText(v);
    }
  }
  const t = el("text", { x: nx, y: ny, "font-size": 11, "text-anchor": "middle", fill: "#333", class: "axis-label" }, g);
  if (which === "y") t.setAttribute("transform", `rotate(-90 ${nx} ${ny})`);
  t.textContent = name;
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
  card.addEventListener("click", (e) => {
    if (e.shiftKey || e.ctrlKey || e.metaKey) {
      // shift-click (or Ctrl/Cmd-click) adds to / removes from the selection
      if (!app.multi.size && app.selected !== null && app.selected !== i) app.multi.add(app.selected);
      if (app.multi.has(i)) app.multi.delete(i); else app.multi.add(i);
    } else {
      app.multi.clear();
    }
    renderMulti();
    select(i);
  });
  card.addEventListener("dragstart", (e) => {
    const ids = app.multi.has(i) ? [...app.multi] : [i];
    e.dataTransfer.setData("text/plain", ids.join(","));
    e.dataTransfer.effectAllowed = "move";
  });
  return card;
}

function renderMulti() {
  app.cards.forEach((c, i) => c.classList.toggle("multi", app.multi.has(i)));
  const n = app.multi.size;
  document.getElementById("multi-note").textContent = n ? `${n} selected (keys and drag apply to all; Esc clears)` : "";
}

function dropZone(zone) {
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    const ids = e.dataTransfer.getData("text/plain").split(",").map((x) => parseInt(x, 10)).filter((x) => !Number.isNaN(x));
    if (!ids.length) return;
    const g = zone.dataset.group;
    if (g === "skip") change("/api/skip", { ids, skipped: true });
    else change("/api/assign", { ids, group: parseInt(g, 10) });
    if (ids.length > 1) { app.multi.clear(); renderMulti(); }
    select(ids[0]);
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
  renderMulti();
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
  revealInList(card);
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

// Scrolls the card's own list so that the card shows, never the page (scrollIntoView scrolled the whole page
// down to the unlabelled list on load).
function revealInList(card) {
  const box = card.parentElement;
  if (!box) return;
  const top = card.offsetTop - box.offsetTop, bottom = top + card.offsetHeight;
  if (top < box.scrollTop) box.scrollTop = top;
  else if (bottom > box.scrollTop + box.clientHeight) box.scrollTop = bottom - box.clientHeight;
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
  if (e.target.tagName === "INPUT") return;
  if ((e.ctrlKey || e.metaKey) && !e.altKey && (e.key === "z" || e.key === "Z")) { e.preventDefault(); undoLast(); return; }
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  if (e.key === "Escape") { app.multi.clear(); renderMulti(); return; }
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
  const ids = targets();
  const many = ids.length > 1;
  if (/^[0-9]$/.test(e.key)) {
    const g = parseInt(e.key, 10);
    if (g > st.groups.length) { showError({ message: `no group ${g}: there are ${st.groups.length}` }, { keepStatus: true }); return; }
    const next = g > 0 && !many ? nextUnlabelled(i) : i;
    change("/api/assign", { ids, group: g }).then((ok) => {
      if (ok && many) { app.multi.clear(); renderMulti(); }
      if (ok && next !== i) select(next);
    });
  } else if (e.key === "s") {
    const next = many ? i : nextUnlabelled(i);
    const skip = many ? true : !st.skipped[i];
    change("/api/skip", { ids, skipped: skip }).then((ok) => {
      if (ok && many) { app.multi.clear(); renderMulti(); }
      if (ok && skip && next !== i) select(next);
    });
  }
}

// ------------------------------------------------------------------------------------------ inference
// "auto" (run until converged, the default) or a number of iterations per chain
function iterationsSetting(text) {
  const t = String(text).trim().toLowerCase();
  return t === "" || t === "auto" ? "auto" : parseInt(t.replace(/[_,]/g, ""), 10);
}

async function runInference() {
  const body = {
    iterations: iterationsSetting(document.getElementById("iterations").value),
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
    if (job.settings) showSettings(job.settings, job.status !== "running");
    if (job.status === "running") { app.polling = setTimeout(poll, 500); return; }
    document.getElementById("infer-btn").disabled = false;
    if (job.status === "error") showError({ message: job.message });
    if (job.status === "done") renderResult(job.result, job.revision);
  }).catch(showError);
}

// The settings of the run whose result is shown; after a reload they refill the form as well.
function showSettings(s, refill) {
  const m = s.margins === null ? "none" : s.margins.join(", ");
  document.getElementById("run-settings").textContent =
    `run settings: ${s.iterations === "auto" ? "until converged" : s.iterations.toLocaleString("en") + " iterations"} × ${s.chains} chain(s), margins ${m}, seed ${s.seed}`;
  if (refill && !app.formTouched) {
    document.getElementById("iterations").value = s.iterations;
    document.getElementById("chains").value = s.chains;
    document.getElementById("margins").value = s.margins === null ? "" : s.margins.join(",");
    document.getElementById("figures").checked = s.figures;
  }
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
  if (res.converged === false) {
    // never folded away: the numbers below are not yet the posterior
    const bad = document.createElement("div");
    bad.className = "not-converged";
    bad.setAttribute("role", "alert");
    const c = res.convergence || {};
    const failing = Object.entries(c.failing || {});
    bad.textContent = `NOT CONVERGED after ${Math.round(c.wall_s || 0)} s: ${failing.length} reported ` +
      `quantit${failing.length === 1 ? "y falls" : "ies fall"} short (` +
      failing.slice(0, 3).map(([k, v]) => `${k}: ${v}`).join("; ") +
      `). Do not trust these numbers or the suggestions yet; label more demonstrations or run again.`;
    out.appendChild(bad);
  }
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
    h.textContent = res.converged === false
      ? "Label these next (ranked from a run that did NOT converge: a rough guide only)"
      : "Label these next (most informative about the constraints)";
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
    img.title = "click: full size";
    img.className = "figure";
    img.addEventListener("click", () => openFigure(img.src, name));
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

// A figure at its full size in an overlay (click or Esc closes it).
function openFigure(src, name) {
  const box = document.getElementById("lightbox");
  const img = document.getElementById("lightbox-img");
  img.src = src;
  img.alt = name;
  box.hidden = false;
}

// "Nice" tick values covering [lo, hi].
function ticks(lo, hi, n) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / Math.max(n, 1), mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((f) => f * mag).find((s) => s >= raw) || 10 * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return out;
}

function tickText(v) {
  const a = Math.abs(v);
  return a >= 1e4 || (a > 0 && a < 1e-3) ? v.toExponential(1) : String(Number(v.toPrecision(4)));
}

// Box plot of each group's returns under the selected-set estimate (min, 10/25/50/75/90 %, max), with a value axis.
function rewardPlot(groups) {
  const w = 340, rowh = 26, h = 50 + rowh * groups.length;
  const svg = document.createElementNS(SVG, "svg");
  svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
  svg.setAttribute("width", w);  // drawn at its own size: scaled to a wide column its text grew to ~30 px
  svg.setAttribute("height", h);
  svg.id = "reward-plot";
  const lo = Math.min(...groups.map((g) => g.quantiles[0])), hi = Math.max(...groups.map((g) => g.quantiles[6]));
  const X = (v) => 90 + (w - 100) * ((v - lo) / (hi - lo || 1));
  el("text", { x: 4, y: 14, "font-size": 11, fill: "#555" }, svg).textContent = "reward per group (selected-set estimate)";
  const axisY = 30 + rowh * groups.length - 8;
  el("line", { x1: X(lo), x2: X(hi), y1: axisY, y2: axisY, stroke: "#555" }, svg);
  for (const v of ticks(lo, hi, 4)) {
    el("line", { x1: X(v), x2: X(v), y1: axisY, y2: axisY + 4, stroke: "#555", class: "tick" }, svg);
    el("text", { x: X(v), y: axisY + 15, "font-size": 10, "text-anchor": "middle", fill: "#333", class: "tick-label" }, svg).textContent = tickText(v);
  }
  el("text", { x: (X(lo) + X(hi)) / 2, y: axisY + 28, "font-size": 10, "text-anchor": "middle", fill: "#555" }, svg).textContent =
    "length-normalised return";
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
  document.getElementById("lightbox").addEventListener("click", () => { document.getElementById("lightbox").hidden = true; });
  document.addEventListener("keydown", (e) => { if (e.key === "Escape") document.getElementById("lightbox").hidden = true; });
  for (const id of ["iterations", "chains", "margins", "figures"]) {
    document.getElementById(id).addEventListener("input", () => { app.formTouched = true; });
  }
  document.getElementById("banner-reload").addEventListener("click", () => location.reload());
}

main();
