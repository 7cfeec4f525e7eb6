// lightemma report: sortable tables and the frame browser. No library, no network: data comes from
// html/data.js (every frame, loaded after the tables are on screen) and html/texts/<k>.js (stage
// texts and camera projections of 64 frames, loaded when one of them is viewed).
"use strict";
(function () {
  const LE = (window.LE = { ready: false, chunks: {}, waiting: {} });
  const PAGE = 60; // frames shown per "show more"
  const GT = "#2ca02c";
  let D = null; // html/data.js
  let shown = []; // frame indices matching the filters, in display order
  let limit = PAGE;
  let observer = null;

  const $ = (id) => document.getElementById(id);
  const el = (tag, attrs, ...children) => {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "text") e.textContent = v;
      else e.setAttribute(k, v);
    }
    for (const c of children) if (c != null) e.append(c);
    return e;
  };
  const SVG = "http://www.w3.org/2000/svg";
  const svgEl = (tag, attrs) => {
    const e = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    return e;
  };
  const fmt = (v, digits) => (v == null ? "–" : Number(v).toFixed(digits));

  // ---- sortable tables -------------------------------------------------------------------------
  function makeSortable(table) {
    table.querySelectorAll("th").forEach((th, col) => {
      th.addEventListener("click", () => {
        const asc = th.getAttribute("aria-sort") !== "ascending";
        table.querySelectorAll("th").forEach((h) => h.removeAttribute("aria-sort"));
        th.setAttribute("aria-sort", asc ? "ascending" : "descending");
        const body = table.tBodies[0];
        const rows = Array.from(body.rows);
        const key = (row) => {
          const cell = row.cells[col];
          if (!cell) return null;
          const s = cell.getAttribute("data-sort");
          return s != null ? Number(s) : cell.textContent.trim();
        };
        rows.sort((a, b) => {
          const x = key(a), y = key(b);
          const xm = x == null || x === "-" || x === "–", ym = y == null || y === "-" || y === "–";
          if (xm || ym) return xm === ym ? 0 : xm ? 1 : -1; // missing values last, either way
          const c = typeof x === "number" && typeof y === "number" ? x - y : String(x).localeCompare(String(y), undefined, { numeric: true });
          return asc ? c : -c;
        });
        rows.forEach((r) => body.append(r));
      });
    });
  }

  // ---- data loading ----------------------------------------------------------------------------
  function loadScript(src, onerror) {
    const s = document.createElement("script");
    s.src = src;
    s.onerror = onerror;
    document.body.append(s);
  }
  LE.data = function (data) {
    D = data;
    setupFilters();
    LE.readyAt = performance.now(); // ms since navigation started
    LE.ready = true;
    route();
  };
  LE.frameId = (j) => D.ids[j];
  LE.chunk = function (c) {
    LE.chunks[c.k] = c.frames;
    for (const fn of LE.waiting[c.k] || []) fn(c.frames);
    delete LE.waiting[c.k];
  };
  function withChunk(k, fn) {
    if (LE.chunks[k]) return fn(LE.chunks[k]);
    const first = !LE.waiting[k];
    (LE.waiting[k] = LE.waiting[k] || []).push(fn);
    if (first) loadScript(`html/texts/${k}.js`, () => { delete LE.waiting[k]; });
  }

  // ---- per-frame values ------------------------------------------------------------------------
  const nModels = () => D.models.length;
  const traj = (arr, j) => {
    const t = arr.slice(12 * j, 12 * j + 12);
    return t[0] == null ? null : t;
  };
  function meanAde(j) {
    let s = 0, n = 0;
    for (let m = 0; m < nModels(); m++) if (D.ade[m][j] != null) { s += D.ade[m][j]; n++; }
    return n ? s / n : null;
  }
  const frameError = (j, m) => (m === "" ? meanAde(j) : D.ade[m][j]);
  const hasTag = (j, t) => (D.tagbits[j] >> t) & 1;
  // safety flags of model m on frame j (docs/definitions.md#safety): 1, 0, or null where it has no value
  const SAFETY = { collides: ["collides"], off_road: ["off_road"], unsafe: ["collides", "off_road"] };
  const flagged = (m, j, which) => SAFETY[which].some((k) => D[k][m][j] === 1);
  const hasSafety = () => ["collides", "off_road"].some((k) => D[k].some((row) => row.some((v) => v != null)));
  const yesNo = (v) => (v == null ? "n/a" : v ? "yes" : "no");
  // the stated intent contradicts the model's own plan ("contra") or what the car did ("contra_gt"): 1, 0 or null
  // (docs/definitions.md#explanation-audit); older data.js files have neither
  const INTENT = ["contra", "contra_gt"];
  const contradicted = (m, j, which) => Boolean(D[which] && D[which][m][j] === 1);
  const hasIntent = () => INTENT.some((k) => D[k] && D[k].some((row) => row.some((v) => v != null)));
  const tagsOf = (j) => D.tags.filter((_, t) => hasTag(j, t));

  // ---- filters and routing ---------------------------------------------------------------------
  function params() {
    const q = location.hash.split("?")[1] || "";
    return new URLSearchParams(q);
  }
  function setupFilters() {
    D.models.forEach((m, i) => $("f-model").append(el("option", { value: String(i), text: m.label })));
    D.tags.forEach((t) => $("f-tag").append(el("option", { value: t, text: t.replace(/_/g, " ") })));
    D.failures.forEach((f, i) => { if (i > 0) $("f-fail").append(el("option", { value: f, text: f.replace(/_/g, " ") })); });
    D.bands.forEach((b, i) => $("f-band").append(el("option", { value: String(i), text: b[2] })));
    LE.hasSafety = hasSafety();
    if (!LE.hasSafety) { // no dataroot (or no map and annotations): nothing to filter on, said once here
      const safe = $("f-safe");
      safe.textContent = "";
      safe.append(el("option", { value: "", text: "no safety values (pass --dataroot)" }));
      safe.disabled = true;
    }
    LE.hasIntent = hasIntent();
    if (!LE.hasIntent) { // no stage-2 texts (or --no-explanations): nothing to filter on, said once here
      const f = $("f-intent");
      f.textContent = "";
      f.append(el("option", { value: "", text: "no stated intents" }));
      f.disabled = true;
    }
    for (const id of ["f-model", "f-tag", "f-fail", "f-band", "f-safe", "f-intent", "f-dis", "f-sort"]) {
      $(id).addEventListener("change", () => {
        const q = new URLSearchParams();
        for (const [key, fid] of [["model", "f-model"], ["tag", "f-tag"], ["fail", "f-fail"], ["band", "f-band"], ["safe", "f-safe"], ["intent", "f-intent"], ["dis", "f-dis"], ["sort", "f-sort"]]) {
          if ($(fid).value && !(key === "sort" && $(fid).value === "frame")) q.set(key, $(fid).value);
        }
        location.hash = "#frames" + (q.toString() ? "?" + q.toString() : "");
      });
    }
    $("more").addEventListener("click", () => { limit += PAGE; drawGrid(); });
  }
  function filtered(p) {
    const m = p.get("model") || "";
    const mi = m === "" ? "" : Number(m);
    const tag = p.get("tag") ? D.tags.indexOf(p.get("tag")) : -1;
    const fail = p.get("fail") ? D.failures.indexOf(p.get("fail")) : -1;
    const band = p.get("band") ? D.bands[Number(p.get("band"))] : null;
    const dis = p.get("dis") ? Number(p.get("dis")) : null;
    const safe = LE.hasSafety && SAFETY[p.get("safe")] ? p.get("safe") : null; // no values: the filter is off
    const intent = LE.hasIntent && INTENT.includes(p.get("intent")) ? p.get("intent") : null;
    const out = [];
    for (let j = 0; j < D.ids.length; j++) {
      if (mi !== "" && D.fail[mi][j] < 0) continue; // not in that model's run
      if (tag >= 0 && !hasTag(j, tag)) continue;
      if (fail >= 0) {
        if (mi !== "" ? D.fail[mi][j] !== fail : !D.fail.some((f) => f[j] === fail)) continue;
      }
      if (band) {
        const e = frameError(j, mi);
        if (e == null || e < band[0] || (band[1] != null && e >= band[1])) continue;
      }
      if (dis != null && !(D.spread[j] >= dis)) continue;
      if (safe && !(mi !== "" ? flagged(mi, j, safe) : D.models.some((_, m) => flagged(m, j, safe)))) continue;
      if (intent && !(mi !== "" ? contradicted(mi, j, intent) : D.models.some((_, m) => contradicted(m, j, intent)))) continue;
      out.push(j);
    }
    const sort = p.get("sort") || "frame";
    const desc = (f) => (a, b) => { const x = f(a), y = f(b); return (y == null ? -Infinity : y) - (x == null ? -Infinity : x); };
    if (sort === "worst") out.sort(desc((j) => frameError(j, mi)));
    if (sort === "spread") out.sort(desc((j) => D.spread[j]));
    return { out, mi };
  }

  function route() {
    const h = location.hash;
    const frames = h.startsWith("#frames");
    const frame = h.startsWith("#frame/");
    $("tables-view").hidden = frames || frame;
    $("frames-view").hidden = !frames;
    $("frame-view").hidden = !frame;
    $("nav-tables").classList.toggle("active", !frames && !frame);
    $("nav-frames").classList.toggle("active", frames || frame);
    if (!LE.ready) return;
    if (frames) showFrames();
    if (frame) showFrame(Number(decodeURIComponent(h.slice(7)).split("?")[0]));
    if (frames || frame) window.scrollTo(0, 0);
  }
  let lastQuery = null;
  function showFrames() {
    const p = params();
    for (const [key, fid] of [["model", "f-model"], ["tag", "f-tag"], ["fail", "f-fail"], ["band", "f-band"], ["safe", "f-safe"], ["intent", "f-intent"], ["dis", "f-dis"], ["sort", "f-sort"]]) {
      $(fid).value = p.get(key) || (key === "sort" ? "frame" : "");
    }
    const q = p.toString();
    if (q !== lastQuery) { limit = PAGE; lastQuery = q; }
    const r = filtered(p);
    shown = r.out;
    LE.lastList = { list: r.out, mi: r.mi, query: q };
    $("frame-count").textContent = `${r.out.length} of ${D.ids.length} frames`;
    drawGrid();
  }

  // ---- thumbnails (drawn when they scroll into view) -------------------------------------------
  function drawGrid() {
    const grid = $("grid");
    grid.textContent = "";
    if (observer) observer.disconnect();
    observer = "IntersectionObserver" in window ? new IntersectionObserver(onVisible, { rootMargin: "200px" }) : null;
    const mi = LE.lastList.mi;
    for (const j of shown.slice(0, limit)) {
      const thumb = el("div", { class: "thumb", "data-frame": String(j) });
      const e = frameError(j, mi);
      const card = el("a", { class: "card", href: `#frame/${j}`, "data-frame": String(j) }, thumb,
        el("div", { class: "caption" }, el("span", { class: "id", text: D.ids[j], title: D.ids[j] }),
          el("span", { class: "muted", text: (e == null ? "not scored" : `ADE ${e.toFixed(2)} m`) + (D.spread[j] != null ? ` · Δ ${D.spread[j].toFixed(1)} m` : "") }),
          (mi !== "" ? contradicted(mi, j, "contra") : D.models.some((_, m) => contradicted(m, j, "contra")))
            ? el("span", { class: "intent-flag", text: "says ≠ plans", title: "the stated intent contradicts the plan" }) : null));
      grid.append(card);
      if (observer) observer.observe(thumb); else fillThumb(thumb);
    }
    $("more").hidden = shown.length <= limit;
  }
  function onVisible(entries) {
    for (const entry of entries) if (entry.isIntersecting) { observer.unobserve(entry.target); fillThumb(entry.target); }
  }
  function fillThumb(thumb) {
    const j = Number(thumb.getAttribute("data-frame"));
    if (D.image[j]) thumb.append(el("img", { src: D.image[j], alt: D.ids[j], loading: "lazy" }));
    else thumb.append(bevSvg(j, LE.lastList.mi === "" ? null : [LE.lastList.mi], false));
  }

  // ---- bird's-eye view ---------------------------------------------------------------------------
  // ego frame: x forward (up on screen), y left (left on screen); origin = the ego now
  function bevSvg(j, models, axes) {
    const paths = [];
    const gt = traj(D.gt, j);
    const list = models || D.models.map((_, m) => m);
    for (const m of list) { const t = traj(D.pred[m], j); if (t) paths.push([D.models[m].color, t, m]); }
    const pts = [[0, 0]];
    for (const t of [gt, ...paths.map((p) => p[1])]) if (t) for (let k = 0; k < 6; k++) pts.push([-t[2 * k + 1], t[2 * k]]);
    const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
    const half = Math.max(5, Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys)) * 0.62;
    const cx = (Math.max(...xs) + Math.min(...xs)) / 2, cy = (Math.max(...ys) + Math.min(...ys)) / 2;
    const W = axes ? 400 : 160, H = axes ? 400 : 90, pad = axes ? 34 : 0;
    const s = Math.min(W - pad, H - pad) / (2 * half);
    const X = (h) => pad + (W - pad) / 2 + (h - cx) * s, Y = (v) => (H - pad) / 2 - (v - cy) * s;
    const svg = svgEl("svg", { viewBox: `0 0 ${W} ${H}`, class: "bev-plot", role: "img", "aria-label": "bird's-eye view" });
    if (axes) {
      const step = niceStep(2 * half);
      for (let v = Math.ceil((cx - half) / step) * step; v <= cx + half; v += step) {
        svg.append(svgEl("line", { x1: X(v), x2: X(v), y1: 0, y2: H - pad, stroke: "#ddd" }));
        const t = svgEl("text", { x: X(v), y: H - pad + 13, "font-size": 10, "text-anchor": "middle" }); t.textContent = `${fmt(-v, 0)}`; svg.append(t);
      }
      for (let v = Math.ceil((cy - half) / step) * step; v <= cy + half; v += step) {
        svg.append(svgEl("line", { x1: pad, x2: W, y1: Y(v), y2: Y(v), stroke: "#ddd" }));
        const t = svgEl("text", { x: pad - 4, y: Y(v) + 3, "font-size": 10, "text-anchor": "end" }); t.textContent = `${fmt(v, 0)}`; svg.append(t);
      }
      const xl = svgEl("text", { x: pad + (W - pad) / 2, y: H - 4, "font-size": 11, "text-anchor": "middle" }); xl.textContent = "y, left ← lateral (m) → right"; svg.append(xl);
      const yl = svgEl("text", { x: 10, y: (H - pad) / 2, "font-size": 11, "text-anchor": "middle", transform: `rotate(-90 10 ${(H - pad) / 2})` }); yl.textContent = "x, forward (m)"; svg.append(yl);
    }
    const line = (t, color, width, dash, cls) => {
      const d = [[0, 0]];
      for (let k = 0; k < 6; k++) d.push([-t[2 * k + 1], t[2 * k]]);
      svg.append(svgEl("polyline", { points: d.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" "), fill: "none", stroke: color, "stroke-width": width, "stroke-dasharray": dash || "", "stroke-linejoin": "round", class: cls }));
    };
    if (axes && D.sim) for (const m of list) { // the planning score's re-simulated path: dotted, the model's colour
      const a = D.sim[m], o = j * 22, d = [];
      if (!a) continue;
      for (let k = 0; k < 11; k++) if (a[o + 2 * k] != null) d.push([-a[o + 2 * k + 1], a[o + 2 * k]]);
      if (d.length > 1) svg.append(svgEl("polyline", { points: d.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" "), fill: "none", stroke: D.models[m].color, "stroke-width": 1.4, "stroke-dasharray": "1 3", class: `sim model-${m}` }));
    }
    for (const [color, t, m] of paths) line(t, color, axes ? 2 : 1.6, "", `pred model-${m}`);
    if (gt) line(gt, GT, axes ? 2.5 : 2, "6 3", "gt"); // dashed on top: never hides a prediction
    svg.append(svgEl("path", { d: `M ${X(0)} ${Y(0) - 6} l -4 9 l 8 0 z`, fill: "#000" }));
    return svg;
  }
  function niceStep(span) {
    const raw = span / 6, p = Math.pow(10, Math.floor(Math.log10(raw)));
    return [1, 2, 5, 10].map((k) => k * p).find((k) => k >= raw);
  }

  // ---- the frame view ----------------------------------------------------------------------------
  function showFrame(j) {
    const view = $("frame-view");
    view.textContent = "";
    if (!(j >= 0 && j < D.ids.length)) { view.append(el("p", { text: "No such frame." })); return; }
    const list = LE.lastList ? LE.lastList.list : [];
    const pos = list.indexOf(j);
    const back = LE.lastList ? "#frames" + (LE.lastList.query ? "?" + LE.lastList.query : "") : "#frames";
    const nav = el("div", { class: "top" },
      el("a", { href: back, id: "back", text: "← frames" }),
      pos > 0 ? el("a", { href: `#frame/${list[pos - 1]}`, id: "prev", text: "‹ previous" }) : null,
      pos >= 0 && pos + 1 < list.length ? el("a", { href: `#frame/${list[pos + 1]}`, id: "next", text: "next ›" }) : null,
      el("h2", { id: "frame-title", text: D.ids[j] }),
      el("span", { class: "muted", text: [D.scene[j], tagsOf(j).join(", ") || "no tag", D.spread[j] != null ? `models disagree by ${D.spread[j].toFixed(1)} m at 3 s` : ""].filter(Boolean).join(" · ") }));
    const legend = el("div", { class: "legend" }, el("span", {}, el("i", { style: `background:${GT}` }), "ground truth (dashed)"),
      ...D.models.map((m) => el("span", {}, el("i", { style: `background:${m.color}` }), m.label)),
      D.sim ? el("span", { class: "muted", text: "dotted: the plan as the planning score re-simulates it" }) : null);
    const camera = el("div", { class: D.image[j] ? "camera" : "camera empty", id: "camera" });
    if (D.image[j]) camera.append(el("img", { src: D.image[j], alt: `camera image of ${D.ids[j]}` }));
    else camera.append(el("p", { class: "muted", text: "No camera image for this frame (imported runs or a dataset not found: pass --dataroot)." }));
    const bev = el("div", { class: "bev" }, bevSvg(j, null, true));
    const metrics = el("table", { id: "frame-metrics", class: "sortable" });
    metrics.append(el("thead", {}, el("tr", {}, ...["Model", "ADE (m)", "FDE (m)", "Outcome", "Collides", "Off-road", "Time (s)", "Tokens in", "Tokens out", "Cost (¢)"].map((h) => el("th", { text: h })))));
    const tb = el("tbody");
    D.models.forEach((m, i) => {
      const f = D.fail[i][j];
      const cells = [fmt(D.ade[i][j], 2), fmt(D.fde[i][j], 2), f < 0 ? "not in run" : D.failures[f], yesNo(D.collides[i][j]), yesNo(D.off_road[i][j]),
        fmt(D.seconds[i][j], 2), fmt(D.tok_in[i][j], 0), fmt(D.tok_out[i][j], 0), fmt(D.cost[i][j], 3)];
      const sorts = [D.ade[i][j], D.fde[i][j], null, D.collides[i][j], D.off_road[i][j], D.seconds[i][j], D.tok_in[i][j], D.tok_out[i][j], D.cost[i][j]];
      const cls = (k) => (k === 3 || k === 4 ? (cells[k] === "yes" ? "flag unsafe" : "flag") : null);
      tb.append(el("tr", { "data-model": String(i) }, el("td", {}, el("span", { class: "swatch", style: `background:${m.color}` }), m.label),
        ...cells.map((c, k) => el("td", Object.assign({ text: c }, sorts[k] == null ? {} : { "data-sort": String(sorts[k]) }, cls(k) ? { class: cls(k) } : {})))));
    });
    metrics.append(tb);
    makeSortable(metrics);
    const texts = el("div", { id: "texts" }, el("p", { class: "muted", text: "loading stage texts…" }));
    view.append(nav, legend, el("div", { class: "panels" }, camera, bev), metrics, texts);
    withChunk(Math.floor(j / D.chunk), (frames) => fillFrame(j, frames[String(j)] || {}));
  }
  function fillFrame(j, entry) {
    if (!location.hash.startsWith(`#frame/${j}`)) return; // the user moved on
    const camera = $("camera");
    if (entry.proj && entry.size && camera) {
      const [w, h] = entry.size;
      const svg = svgEl("svg", { viewBox: `0 0 ${w} ${h}`, preserveAspectRatio: "none", id: "projection" });
      const draw = (flat, color, width, dash, cls) => {
        if (!flat) return;
        const pts = [];
        for (let k = 0; k + 1 < flat.length; k += 2) pts.push(`${flat[k]},${flat[k + 1]}`);
        svg.append(svgEl("polyline", { points: pts.join(" "), fill: "none", stroke: color, "stroke-width": width, "stroke-dasharray": dash || "", "stroke-linejoin": "round", class: cls }));
      };
      entry.proj.slice(1).forEach((flat, m) => draw(flat, D.models[m].color, 2, "", `pred model-${m}`));
      draw(entry.proj[0], GT, 2.5, "7 4", "gt");
      camera.append(svg);
    }
    const box = $("texts");
    box.textContent = "";
    D.models.forEach((m, i) => {
      const t = (entry.texts || [])[i];
      const dl = el("dl");
      const read = (entry.intent || [])[i];
      for (const [k, name] of [[0, "1 · Scene"], [1, "2 · Intent"], [2, "3 · Answer"]]) {
        const dd = el("dd", { text: t && t[k] ? t[k] : "—" });
        if (k === 0 && read && read.objects.length) dd.append(el("p", { class: "read-objects contradicts", text: "Described objects: " + read.objects.join(", ") }));
        if (k === 1 && read) { // the read intent (rules intent@lightemma/1), its contradiction highlighted
          const bad = read.verdict === "contradicts";
          const truth = read.truth == null ? "" : ` · against what the car did: ${read.truth}`;
          dd.classList.toggle("contradicts", bad);
          dd.append(el("p", { class: "read-intent" + (bad ? " contradicts" : ""), "data-verdict": read.verdict,
            text: `Read intent: ${read.lon.replace(/_/g, " ")} / ${read.lat.replace(/_/g, " ")} · against its plan: ${read.verdict}` + (read.reason ? ` (${read.reason})` : "") + truth }));
        }
        dl.append(el("dt", { text: name }), dd);
      }
      box.append(el("section", { class: "model-texts", "data-model": String(i) }, el("h4", {}, el("span", { class: "swatch", style: `background:${m.color}` }), m.label), dl));
    });
  }

  // ---- start -------------------------------------------------------------------------------------
  document.querySelectorAll("table.sortable").forEach(makeSortable);
  window.addEventListener("hashchange", route);
  route();
  loadScript("html/data.js", () => {
    $("frame-count").textContent = "html/data.js could not be read: the frame browser needs the html/ folder beside index.html.";
  });
})();
