// rfsas dashboard: draws the backend's snapshots (local metres, east/north) as SVG.
// Read-only; reconnects by itself when the server goes away.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const token = new URLSearchParams(location.search).get("token");
const withToken = (path) => (token ? `${path}?token=${encodeURIComponent(token)}` : path);
const RAY_M = 150;
let site = null;
let view = null; // {x0, y0, w, h} in metres
let retryMs = 250;

function el(tag, attrs, parent) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (parent) parent.appendChild(node);
  return node;
}
function clear(id) {
  const g = document.getElementById(id);
  while (g.firstChild) g.removeChild(g.firstChild);
  return g;
}
const px = (x) => x;
const py = (y) => -y; // SVG y grows downwards; north is up
const rad = (deg) => (deg * Math.PI) / 180;
const along = (x, y, az, r) => [x + r * Math.sin(rad(az)), y + r * Math.cos(rad(az))];

function setStatus(state, text) {
  const s = document.getElementById("status");
  s.className = `status-${state}`;
  s.dataset.status = state;
  s.textContent = text;
}

function fitView(points) {
  let xs = points.map((p) => p[0]);
  let ys = points.map((p) => p[1]);
  if (!xs.length) { xs = [-50, 50]; ys = [-50, 50]; }
  const pad = 10;
  const x0 = Math.min(...xs) - pad, x1 = Math.max(...xs) + pad;
  const y0 = Math.min(...ys) - pad, y1 = Math.max(...ys) + pad;
  view = { x0, y0, w: x1 - x0, h: y1 - y0 };
  document.getElementById("map").setAttribute("viewBox", `${x0} ${-y1} ${x1 - x0} ${y1 - y0}`);
}

function drawSite() {
  const g = clear("layer-site");
  const pts = [];
  // a scenario's roads run far out; frame the map on buildings and sensors
  for (const f of site.map) {
    const d = f.points.map((p, i) => `${i ? "L" : "M"}${px(p[0])},${py(p[1])}`).join(" ");
    el("path", { d: d + (f.closed ? " Z" : ""), class: ["building", "road", "area"].includes(f.kind) ? f.kind : (f.closed ? "area" : "line"), "data-name": f.name }, g);
    if (f.kind !== "road") pts.push(...f.points);
  }
  for (const s of site.sensors) pts.push([s.x_m, s.y_m]);
  fitView(pts);
  drawTiles();
}

// optional background tiles (Web Mercator), placed by metres per degree at the origin
function drawTiles() {
  const g = clear("layer-tiles");
  if (!site.tiles || !site.origin || !site.m_per_deg || !view) return;
  const o = site.origin, k = site.m_per_deg;
  const toLat = (y) => o.lat_deg + y / k.lat, toLon = (x) => o.lon_deg + x / k.lon;
  // tiles about half the view wide, over the view and a margin as wide (the page is
  // rarely the view's shape)
  const z = Math.max(0, Math.min(19, Math.round(Math.log2((40075016 * Math.cos(rad(o.lat_deg))) / (view.w / 2)))));
  const m = Math.max(view.w, view.h);
  const area = { x0: view.x0 - m, y0: view.y0 - m, w: view.w + 2 * m, h: view.h + 2 * m };
  const n = 2 ** z;
  const tx = (lon) => ((lon + 180) / 360) * n;
  const ty = (lat) => ((1 - Math.log(Math.tan(rad(lat)) + 1 / Math.cos(rad(lat))) / Math.PI) / 2) * n;
  const lonOf = (x) => (x / n) * 360 - 180;
  const latOf = (y) => (Math.atan(Math.sinh(Math.PI * (1 - (2 * y) / n))) * 180) / Math.PI;
  const xa = Math.floor(tx(toLon(area.x0))), xb = Math.floor(tx(toLon(area.x0 + area.w)));
  const ya = Math.floor(ty(toLat(area.y0 + area.h))), yb = Math.floor(ty(toLat(area.y0)));
  if ((xb - xa + 1) * (yb - ya + 1) > 64) return;
  for (let x = xa; x <= xb; x++) {
    for (let y = ya; y <= yb; y++) {
      const west = (lonOf(x) - o.lon_deg) * k.lon, east = (lonOf(x + 1) - o.lon_deg) * k.lon;
      const north = (latOf(y) - o.lat_deg) * k.lat, south = (latOf(y + 1) - o.lat_deg) * k.lat;
      const href = site.tiles.replace("{z}", z).replace("{x}", x).replace("{y}", y);
      el("image", { href, x: west, y: -north, width: east - west, height: north - south, preserveAspectRatio: "none" }, g);
    }
  }
}

function wedge(x, y, heading, fov, r) {
  const a = heading - fov / 2, b = heading + fov / 2;
  const [xa, ya] = along(x, y, a, r), [xb, yb] = along(x, y, b, r);
  const large = fov > 180 ? 1 : 0;
  return `M${x},${-y} L${xa},${-ya} A${r},${r} 0 ${large} 1 ${xb},${-yb} Z`;
}

function draw(snap) {
  const size = view ? view.w / 60 : 2;
  const sensors = clear("layer-sensors"), fov = clear("layer-fov"), labels = clear("layer-labels");
  for (const s of snap.sensors) {
    if (s.x_m == null) continue;
    el("path", { d: wedge(s.x_m, s.y_m, s.heading_deg, s.fov_deg, RAY_M / 3), class: "fov", "data-id": s.id }, fov);
    const [x, y] = [px(s.x_m), py(s.y_m)];
    el("path", { d: `M${x},${y - size} L${x + size * 0.8},${y + size * 0.6} L${x - size * 0.8},${y + size * 0.6} Z`, class: s.heard ? "sensor" : "sensor sensor-silent", "data-id": s.id }, sensors);
    // labels sit in a layer under the fixes: a fix is never hidden by a sensor's name
    el("text", { x: x + size, y: y - size, class: "label", "font-size": size * 1.1, "data-id": s.id }, labels).textContent = s.id;
  }
  const rays = clear("layer-bearings");
  for (const b of snap.bearings) {
    const [x1, y1] = along(b.x_m, b.y_m, b.azimuth_deg, RAY_M);
    el("line", { x1: px(b.x_m), y1: py(b.y_m), x2: px(x1), y2: py(y1), class: "bearing", "data-sensor": b.sensor_id, "data-emitter": b.emitter }, rays);
  }
  const tracks = clear("layer-tracks");
  for (const t of snap.tracks) {
    if (t.points.length < 2) continue;
    el("polyline", { points: t.points.map((p) => `${px(p[0])},${py(p[1])}`).join(" "), class: "track", "data-emitter": t.emitter }, tracks);
  }
  const fixes = clear("layer-fixes");
  for (const f of snap.fixes) {
    const flagged = f.ok ? "" : "-flagged";
    const e = f.ellipse;
    if (e && e.semi_major_m < 500) {
      // SVG rotation is clockwise from +x on screen; the major axis is at compass orientation_deg
      el("ellipse", { cx: px(f.x_m), cy: py(f.y_m), rx: Math.max(e.semi_major_m, 0.05), ry: Math.max(e.semi_minor_m, 0.05), transform: `rotate(${e.orientation_deg - 90} ${px(f.x_m)} ${py(f.y_m)})`, class: `ellipse${flagged ? " ellipse-flagged" : ""}`, "data-emitter": f.emitter, "data-sigma": e.n_sigma }, fixes);
    }
    el("circle", { cx: px(f.x_m), cy: py(f.y_m), r: size / 2, class: `fix${flagged ? " fix-flagged" : ""}`, "data-emitter": f.emitter, "data-status": f.status }, fixes);
  }
  const vg = clear("layer-vehicle");
  const info = document.getElementById("vehicle-info");
  const v = snap.vehicle;
  if (v && v.x_m != null) {
    const colour = { brake: "#c62828", caution: "#f9a825", clear: "#2e7d32" }[snap.advisory] || "#607d8b";
    el("rect", { x: px(v.x_m) - v.width_m / 2, y: py(v.y_m) - v.length_m / 2, width: v.width_m, height: v.length_m, fill: colour, class: "vehicle", transform: `rotate(${v.heading_deg} ${px(v.x_m)} ${py(v.y_m)})`, "data-advisory": snap.advisory }, vg);
    info.textContent = `vehicle ${v.speed_mps.toFixed(1)} m/s, heading ${v.heading_deg.toFixed(0)}°`;
  } else {
    info.textContent = "no vehicle state";
  }
  const adv = document.getElementById("advisory");
  // every link silent: no advisory is backed by a sensor any more, say so instead
  adv.textContent = snap.stale ? "NO DATA: links silent" : snap.advisory.toUpperCase();
  adv.className = snap.stale ? "adv-stale" : `adv-${snap.advisory}`;
  adv.dataset.advisory = snap.advisory;
  adv.dataset.stale = snap.stale ? "yes" : "no";
  drawScale();
  drawTimeline(snap.timeline);
  drawTables(snap);
}

// a scale bar of a round length about 100 px long (the map keeps its aspect: "meet")
function drawScale() {
  const svg = document.getElementById("map"), bar = document.getElementById("scalebar");
  const box = svg.getBoundingClientRect();
  if (!view || !box.width || !box.height) return;
  const pxPerM = Math.min(box.width / view.w, box.height / view.h);
  const want = 100 / pxPerM, p = 10 ** Math.floor(Math.log10(want));
  const metres = [1, 2, 5, 10].map((k) => k * p).filter((m) => m <= want).pop();
  const len = metres * pxPerM;
  while (bar.firstChild) bar.removeChild(bar.firstChild);
  bar.setAttribute("width", len + 10);
  el("path", { d: `M5,14 V20 H${5 + len} V14`, class: "scale-line" }, bar);
  el("text", { x: 5 + len / 2, y: 11, class: "scale-text" }, bar).textContent = metres >= 1000 ? `${metres / 1000} km` : `${metres} m`;
  bar.dataset.metres = metres;
  bar.dataset.px = len.toFixed(1);
}

// a round step (1, 2 or 5 × 10^k) that puts about `count` ticks over `span`
function niceStep(span, count) {
  const raw = span / count, p = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((k) => k * p).find((s) => s >= raw);
}

function drawTimeline(points) {
  const g = document.getElementById("timeline");
  while (g.firstChild) g.removeChild(g.firstChild);
  if (!points.length) return;
  const t0 = points[0][0], t1 = Math.max(points[points.length - 1][0], t0 + 1);
  const x = (t) => ((t - t0) / (t1 - t0)) * 300;
  const y = (r) => 100 - ((Math.log10(Math.max(r, 1e-4)) + 4) / 4) * 95; // 1e-4 … 1, log scale
  const colours = { brake: "#c62828", caution: "#f9a825", clear: "#a5d6a7", none: "#eceff1" };
  for (let i = 0; i < points.length; i++) {
    const next = i + 1 < points.length ? points[i + 1][0] : t1;
    el("rect", { x: x(points[i][0]), y: 100, width: Math.max(x(next) - x(points[i][0]), 0.5), height: 10, fill: colours[points[i][2]] || "#eceff1" }, g);
  }
  const line = points.filter((p) => p[1] != null).map((p) => `${x(p[0])},${y(p[1])}`);
  if (line.length) el("polyline", { points: line.join(" "), fill: "none", stroke: "#c62828", "stroke-width": 1.2 }, g);
  el("text", { x: 2, y: 10, "font-size": 8, fill: "#555" }, g).textContent = "risk (log, 1e-4…1)";
  // time axis: seconds before the latest step, at round steps
  const span = (t1 - t0) / 1e9, step = niceStep(Math.max(span, 1), 4);
  for (let ago = 0; ago <= span + 1e-9; ago += step) {
    const tx = x(t1 - ago * 1e9);
    el("line", { x1: tx, x2: tx, y1: 110, y2: 113, stroke: "#555", "stroke-width": 0.6, class: "tick" }, g);
    const label = ago === 0 ? "now" : `−${+ago.toFixed(3)} s`;
    el("text", { x: tx, y: 121, "font-size": 7, fill: "#555", "text-anchor": ago === 0 ? "end" : tx < 15 ? "start" : "middle", class: "tick-label" }, g).textContent = label;
  }
}

function cell(row, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  row.appendChild(td);
}

function drawTables(snap) {
  const emitters = document.querySelector("#emitters tbody");
  emitters.replaceChildren();
  const advisory = Object.fromEntries(snap.tracks.map((t) => [t.emitter, t.advisory]));
  for (const f of snap.fixes) {
    const row = document.createElement("tr");
    cell(row, f.emitter); // the 16 hex digits every other output shows
    cell(row, f.lat_deg != null ? `${f.lat_deg.toFixed(6)}, ${f.lon_deg.toFixed(6)}` : `${f.x_m}, ${f.y_m} m`);
    cell(row, f.ellipse ? (f.ellipse.semi_major_m / f.ellipse.n_sigma).toFixed(1) : "–");
    cell(row, advisory[f.emitter] || f.status);
    emitters.appendChild(row);
  }
  const links = document.querySelector("#links tbody");
  links.replaceChildren();
  for (const l of snap.links) {
    const row = document.createElement("tr");
    row.dataset.sensor = l.sensor_id;
    cell(row, l.sensor_id);
    cell(row, l.state, `state-${l.state}`);
    cell(row, String(l.messages));
    cell(row, String(l.lost));
    cell(row, l.p50_ms == null ? "–" : String(l.p50_ms));
    links.appendChild(row);
  }
  const rejected = Object.entries(snap.link_stats).filter(([k, v]) => k.startsWith("rejected.") && v > 0);
  document.getElementById("rejections").textContent = rejected.length
    ? "rejected: " + rejected.map(([k, v]) => `${k.slice(9)} ${v}`).join(", ")
    : `verified ${snap.link_stats.verified ?? 0}, none rejected`;
}

async function loadSite() {
  const r = await fetch(withToken("api/site"), { cache: "no-store" });
  if (!r.ok) throw new Error(`site: HTTP ${r.status}`);
  site = await r.json();
  document.getElementById("sigma").textContent = site.ellipse_sigma;
  drawSite();
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${scheme}://${location.host}/${withToken("ws")}`);
  ws.onopen = () => { retryMs = 250; setStatus("live", "live"); };
  ws.onmessage = (ev) => draw(JSON.parse(ev.data));
  ws.onclose = () => {
    setStatus("reconnecting", "reconnecting…");
    setTimeout(start, retryMs);
    retryMs = Math.min(retryMs * 2, 2000);
  };
}

// the page arrives with the site and the latest snapshot in it: draw them at once
function drawFirstState() {
  const block = document.getElementById("first-state");
  if (!block) return;
  const first = JSON.parse(block.textContent);
  site = first.site;
  document.getElementById("sigma").textContent = site.ellipse_sigma;
  drawSite();
  draw(first.state);
}

async function start() {
  try {
    await loadSite();
    connect();
  } catch (err) {
    setStatus("reconnecting", "reconnecting…");
    setTimeout(start, retryMs);
    retryMs = Math.min(retryMs * 2, 2000);
  }
}

drawFirstState();
window.addEventListener("resize", drawScale);
start();
