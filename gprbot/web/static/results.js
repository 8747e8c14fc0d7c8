// gprbot: one run's results (console Results tab and report.html): summary, pipe table, 3D viewer,
// map, B-scans and sections, downloads. `env` says where files and pictures come from and loads three.js.
"use strict";
(function () {
  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") node.className = v; else if (k === "text") node.textContent = v; else node.setAttribute(k, v);
    }
    for (const c of children) if (c != null) node.append(c);
    return node;
  }
  const fmt = (v, d) => (v == null || Number.isNaN(v) ? "—" : Number(v).toFixed(d));
  const size = (n) => (n > 1e6 ? (n / 1e6).toFixed(1) + " MB" : n > 1e3 ? (n / 1e3).toFixed(1) + " kB" : n + " B");

  function summaryPanel(doc) {
    const s = doc.summary || {}, dl = el("dl");
    const rows = [["run", doc.run], ["source", s.source], ["lines", s.lines], ["pipes found", s.pipes_found],
      ["rebars found", s.rebars_found], ["velocity", s.velocity_m_per_ns != null ? `${fmt(s.velocity_m_per_ns, 4)} m/ns (${s.velocity_estimated ? "estimated from hyperbolas" : "from the configured permittivity"})` : null],
      ["sparse / dense points", `${s.sparse_points ?? "—"} / ${s.dense_points ?? "—"}`], ["scene (simulated)", s.scene]];
    for (const [k, v] of rows) if (v != null) dl.append(el("dt", { text: k }), el("dd", { text: String(v) }));
    if (!doc.complete) dl.append(el("dt", { text: "state" }), el("dd", { class: "err", text: "no summary.json yet: the run is still being processed or was cut short" }));
    return el("div", { class: "panel" }, el("h2", { text: "Run" }), dl);
  }

  function pipeTable(doc) {
    const pipes = (doc.pipes && doc.pipes.pipes) || [];
    const table = el("table", { id: "pipe-table" }, el("tr", {}, ...["", "pipe", "axis start → end (x, y, z m)", "length (m)",
      "cover (m)", "diameter (m)", "confidence", "slices"].map((h) => el("th", { text: h }))));
    for (const p of pipes) {
      const e = p.endpoints_m.map((q) => `(${q.map((c) => fmt(c, 2)).join(", ")})`).join(" → ");
      table.append(el("tr", {}, el("td", {}, el("span", { class: "swatch", style: `background:${p.colour}` })), el("td", { text: `#${p.id}` }),
        el("td", { text: e }), el("td", { text: fmt(p.length_m, 2) }), el("td", { text: fmt(p.depth_of_cover_m, 3) }),
        el("td", { text: fmt(p.diameter_m, 3) }), el("td", { text: fmt(p.confidence, 2) }), el("td", { text: p.n_slices })));
    }
    const panel = el("div", { class: "panel wide" }, el("h2", { text: `Pipes (${pipes.length})` }), table);
    if (!pipes.length) panel.append(el("p", { class: "hint", text: "no pipe found in this run" }));
    if (doc.pipes && doc.pipes.meta) panel.append(el("p", { class: "hint", text: doc.pipes.meta.frame || "" }));
    return panel;
  }

  function viewerPanel(doc, env) {
    const canvas = el("canvas", { id: "viewer", width: 760, height: 460 });
    const note = el("div", { class: "hint", id: "viewer-note", text: "loading three.js…" });
    const toggles = el("div", { class: "controls" });
    const panel = el("div", { class: "panel wide" }, el("h2", { text: "3D: sparse (grey) and dense (pipe colours) clouds, pipes, surveyed area, depth scale" }), toggles, canvas, note);
    env.loadThree().then((THREE) => {
      if (!canvas.isConnected) return;  // another run was chosen meanwhile
      const viewer = GprViewer.create(canvas, THREE, doc);
      for (const name of ["sparse", "dense", "pipes"]) {
        const box = el("input", { type: "checkbox", id: `show-${name}`, checked: "" });
        box.addEventListener("change", () => viewer.show(name, box.checked));
        toggles.append(el("label", {}, box, ` ${name}`));
      }
      note.textContent = `${viewer.points} points, ${viewer.pipes} pipes — drag to turn, wheel to zoom, shift-drag to pan`;
      window.gprViewer = viewer;
    }).catch((err) => { note.textContent = `3D viewer unavailable: ${err}`; note.className = "err"; });
    return panel;
  }

  function picturesPanel(doc, env) {
    const box = el("div", { class: "pictures" });
    if (doc.map) box.append(el("figure", {}, el("img", { src: env.picture(doc.map), alt: "map", id: "map-picture" }), el("figcaption", { text: "map: pipes found, survey lines" })));
    for (const line of doc.lines) {
      if (line.bscan) box.append(el("figure", {}, el("img", { src: env.picture(line.bscan), alt: line.bscan }), el("figcaption", { text: `line ${line.line}: B-scan (time and depth axes)` })));
      if (line.section) box.append(el("figure", {}, el("img", { src: env.picture(line.section), alt: line.section }), el("figcaption", { text: `line ${line.line}: migrated section, detections` })));
    }
    return el("div", { class: "panel full" }, el("h2", { text: "Map, B-scans and sections" }), box);
  }

  function downloadsPanel(doc, env) {
    const table = el("table", { id: "downloads" });
    for (const f of doc.files) table.append(el("tr", {}, el("td", {}, el("a", { href: env.url(f.name), download: f.name.split("/").pop(), text: f.name })), el("td", { text: size(f.size) })));
    return el("div", { class: "panel" }, el("h2", { text: `Files (${doc.files.length})` }), table);
  }

  function render(container, doc, env) {
    container.replaceChildren(el("div", { class: "grid" }, summaryPanel(doc), pipeTable(doc), viewerPanel(doc, env), downloadsPanel(doc, env), picturesPanel(doc, env)));
  }

  window.GprResults = { render, el };
})();
