// gprbot: drawing helpers shared by the console and report.html (plain script, no imports).
"use strict";
(function () {
  const MARGIN = { left: 52, right: 56, top: 10, bottom: 34 };
  const AXIS = "#9aa3ad", GRID = "#2a3038";

  function b64bytes(text) {
    const raw = atob(text), out = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) out[i] = raw.charCodeAt(i);
    return out;
  }
  function b64int16(text) { const b = b64bytes(text); return new Int16Array(b.buffer, b.byteOffset, b.length / 2); }
  function b64float32(text) { const b = b64bytes(text); return new Float32Array(b.buffer, b.byteOffset, b.length / 4); }

  // 256-entry RGB tables; radargrams are signed (-1..1 → 0..255), magnitudes 0..1 → 0..255.
  const luts = {};
  function lut(name) {
    if (luts[name]) return luts[name];
    const t = new Uint8Array(256 * 3);
    for (let i = 0; i < 256; i++) {
      const u = i / 255;
      let r, g, b;
      if (name === "bwr") {
        const s = 2 * u - 1;
        r = s > 0 ? 1 : 1 + s; b = s < 0 ? 1 : 1 - s; g = 1 - Math.abs(s);
        r = 0.1 + 0.9 * r; b = 0.1 + 0.9 * b; g = 0.1 + 0.9 * g; // blue negative, white zero, red positive
      } else if (name === "bone") {
        r = u < 0.75 ? u * 0.9 : 0.675 + (u - 0.75) * 1.3; g = u < 0.375 ? u * 0.85 : u < 0.75 ? 0.32 + (u - 0.375) * 1.1 : 0.73 + (u - 0.75) * 1.08;
        b = u < 0.375 ? u * 1.2 : 0.45 + (u - 0.375) * 0.88;
      } else { r = g = b = u; }
      t[3 * i] = Math.round(255 * Math.min(1, Math.max(0, r)));
      t[3 * i + 1] = Math.round(255 * Math.min(1, Math.max(0, g)));
      t[3 * i + 2] = Math.round(255 * Math.min(1, Math.max(0, b)));
    }
    return (luts[name] = t);
  }

  function niceStep(span, count) {
    const raw = Math.max(span, 1e-9) / count, p = Math.pow(10, Math.floor(Math.log10(raw)));
    for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
    return 10 * p;
  }

  function ticks(ctx, x0, y0, w, h, xr, yr, xLabel, yLabel, y2) {
    ctx.strokeStyle = AXIS; ctx.fillStyle = AXIS; ctx.lineWidth = 1; ctx.font = "11px system-ui, sans-serif";
    ctx.strokeRect(x0 + 0.5, y0 + 0.5, w, h);
    const xs = niceStep(xr[1] - xr[0], 6);
    ctx.textAlign = "center"; ctx.textBaseline = "top";
    for (let v = Math.ceil(xr[0] / xs) * xs; v <= xr[1] + 1e-9; v += xs) {
      const px = x0 + (v - xr[0]) / (xr[1] - xr[0] || 1) * w;
      ctx.beginPath(); ctx.moveTo(px, y0 + h); ctx.lineTo(px, y0 + h + 4); ctx.stroke();
      ctx.fillText(+v.toFixed(3) + "", px, y0 + h + 6);
    }
    ctx.fillText(xLabel, x0 + w / 2, y0 + h + 19);
    const ylo = Math.min(yr[0], yr[1]), yhi = Math.max(yr[0], yr[1]), ys = niceStep(yhi - ylo, 5);
    ctx.textAlign = "right"; ctx.textBaseline = "middle";
    for (let v = Math.ceil(ylo / ys) * ys; v <= yhi + 1e-9; v += ys) {
      const py = y0 + (v - yr[0]) / (yr[1] - yr[0] || 1) * h;
      ctx.beginPath(); ctx.moveTo(x0 - 4, py); ctx.lineTo(x0, py); ctx.stroke();
      ctx.fillText(+v.toFixed(3) + "", x0 - 6, py);
    }
    ctx.save(); ctx.translate(12, y0 + h / 2); ctx.rotate(-Math.PI / 2); ctx.textAlign = "center";
    ctx.fillText(yLabel, 0, 0); ctx.restore();
    if (y2) { // a second vertical scale on the right (depth from time at a velocity)
      const span = y2.range[1] - y2.range[0], s2 = niceStep(span, 5);
      ctx.textAlign = "left";
      for (let v = Math.ceil(y2.range[0] / s2) * s2; v <= y2.range[1] + 1e-9; v += s2) {
        const py = y0 + (v - y2.range[0]) / (span || 1) * h;
        ctx.beginPath(); ctx.moveTo(x0 + w, py); ctx.lineTo(x0 + w + 4, py); ctx.stroke();
        ctx.fillText(+v.toFixed(3) + "", x0 + w + 6, py);
      }
      ctx.save(); ctx.translate(x0 + w + 48, y0 + h / 2); ctx.rotate(Math.PI / 2); ctx.textAlign = "center";
      ctx.fillText(y2.label, 0, 0); ctx.restore();
    }
  }

  // The current line: columns (Int16Array each, one per trace) → image with gain, time-power gain,
  // optional mean-trace removal; the newest traces on the right once the line fills the width.
  function radargram(canvas, line, opts) {
    const ctx = canvas.getContext("2d");
    ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    const w = canvas.width - MARGIN.left - MARGIN.right, h = canvas.height - MARGIN.top - MARGIN.bottom;
    if (!line || !line.columns.length) {
      ctx.fillStyle = AXIS; ctx.font = "13px system-ui"; ctx.fillText("waiting for traces…", MARGIN.left + 10, MARGIN.top + 20);
      return { drawn: 0 };
    }
    // The screen spans the planned line length (or, for a long line, the last `w` traces' distance):
    // traces land where the robot was, so the picture fills from left to right as the line is driven.
    const m = line.samples, n = line.columns.length, dx = line.metresPerTrace || 0.005;
    const windowM = Math.max(dx, Math.min(opts.lineLength_m || n * dx, w * dx));
    const xEnd = line.columns[n - 1].x_m, xStart = Math.max(line.columns[0].x_m, xEnd - windowM);
    let first = 0;
    while (first < n - 1 && line.columns[first].x_m < xStart) first++;
    const cols = line.columns.slice(first);
    // dewow: minus each trace's running mean over about 1.5 periods of the antenna's centre frequency;
    // background: minus the line's mean (dewowed) trace, which removes the direct and ground waves' band
    const half = Math.max(1, Math.round(0.75 * 1000 / (opts.frequency_mhz || 900) / line.dt_ns)), sums = new Float64Array(m + 1);
    const dewowed = (v) => {
      if (!opts.dewow) return v;
      const out = new Float32Array(m);
      for (let k = 0; k < m; k++) sums[k + 1] = sums[k] + v[k];
      for (let k = 0; k < m; k++) { const a = Math.max(0, k - half), b = Math.min(m, k + half + 1); out[k] = v[k] - (sums[b] - sums[a]) / (b - a); }
      return out;
    };
    const mean = new Float32Array(m), shown = cols.map((c) => dewowed(c.values));
    if (opts.background) {
      for (const c of first > 0 ? line.columns.map((c) => dewowed(c.values)) : shown) for (let k = 0; k < m; k++) mean[k] += c[k];
      for (let k = 0; k < m; k++) mean[k] /= n;
    }
    const gain = Math.pow(10, opts.gainDb / 20), tgain = new Float32Array(m);
    for (let k = 0; k < m; k++) {
      const t = Math.max(0, k * line.dt_ns - line.t0_ns);
      tgain[k] = gain * Math.pow(1 + t, opts.tpow);
    }
    const img = new Float32Array(cols.length * m);
    for (let j = 0; j < cols.length; j++) for (let k = 0; k < m; k++) img[k * cols.length + j] = (shown[j][k] - mean[k]) * tgain[k];
    const sample = [];
    for (let i = 0; i < img.length; i += 7) sample.push(Math.abs(img[i]));
    sample.sort((a, b) => a - b);
    const clip = sample[Math.floor(0.99 * (sample.length - 1))] || 1;
    const table = lut(opts.cmap), off = document.createElement("canvas");
    off.width = cols.length; off.height = m;
    const octx = off.getContext("2d"), data = octx.createImageData(cols.length, m);
    for (let i = 0; i < img.length; i++) {
      const u = Math.max(-1, Math.min(1, img[i] / clip)), idx = Math.round((u + 1) * 127.5);
      data.data[4 * i] = table[3 * idx]; data.data[4 * i + 1] = table[3 * idx + 1];
      data.data[4 * i + 2] = table[3 * idx + 2]; data.data[4 * i + 3] = 255;
    }
    octx.putImageData(data, 0, 0);
    ctx.imageSmoothingEnabled = false;
    const x0 = cols[0].x_m, x1 = x0 + windowM, spanPx = Math.max(1, ((xEnd - x0) + dx) / windowM * w);
    ctx.drawImage(off, MARGIN.left, MARGIN.top, Math.min(w, spanPx), h);
    const tEnd = (m - 1) * line.dt_ns - line.t0_ns, v = opts.velocity || 0.1;
    ticks(ctx, MARGIN.left, MARGIN.top, w, h, [x0, x1], [-line.t0_ns, tEnd],
          "distance along the line (m, fused poses)", "t (ns)",
          { range: [-line.t0_ns * v / 2, tEnd * v / 2], label: `depth (m) at v = ${v.toFixed(3)} m/ns` });
    return { drawn: cols.length };
  }

  // A migrated section: magnitude (uint8, z × x) in the bone map with detections circled.
  function section(canvas, sec, detections) {
    const ctx = canvas.getContext("2d"), ml = 44, mr = 8, mt = 6, mb = 30;
    ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    const w = canvas.width - ml - mr, h = canvas.height - mt - mb, pix = b64bytes(sec.data), table = lut("bone");
    const off = document.createElement("canvas"); off.width = sec.w; off.height = sec.h;
    const octx = off.getContext("2d"), data = octx.createImageData(sec.w, sec.h);
    for (let i = 0; i < pix.length; i++) {
      data.data[4 * i] = table[3 * pix[i]]; data.data[4 * i + 1] = table[3 * pix[i] + 1];
      data.data[4 * i + 2] = table[3 * pix[i] + 2]; data.data[4 * i + 3] = 255;
    }
    octx.putImageData(data, 0, 0);
    ctx.imageSmoothingEnabled = true; ctx.drawImage(off, ml, mt, w, h);
    const sx = w / ((sec.x1 - sec.x0) || 1), sz = h / ((sec.z1 - sec.z0) || 1);
    ctx.strokeStyle = "#ffd400"; ctx.lineWidth = 2;
    for (const d of detections || []) {
      const px = ml + (d.along_m - sec.x0) * sx, pz = mt + (d.depth_m - sec.z0) * sz;
      ctx.beginPath(); ctx.arc(px, pz, Math.max(4, d.radius_m * sx), 0, 2 * Math.PI); ctx.stroke();
    }
    ticks(ctx, ml, mt, w, h, [sec.x0, sec.x1], [sec.z0, sec.z1], "x along the line (m)", "depth (m)");
  }

  // The top-down map: plan, tracks, robot, detections, slice points, and pipes once known.
  function map(canvas, state) {
    const ctx = canvas.getContext("2d"), ml = 48, mr = 12, mt = 10, mb = 34;
    ctx.fillStyle = "#0b0d10"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    const a = state.area || [0, 2, 0, 1];
    let [x0, x1, y0, y1] = [a[0] - 0.2, a[1] + 0.2, a[2] - 0.2, a[3] + 0.2];
    const w = canvas.width - ml - mr, h = canvas.height - mt - mb;
    const scale = Math.min(w / (x1 - x0), h / (y1 - y0));
    x1 = x0 + w / scale; y1 = y0 + h / scale;
    const X = (x) => ml + (x - x0) * scale, Y = (y) => mt + h - (y - y0) * scale;
    const step = niceStep(Math.max(x1 - x0, y1 - y0), 8);
    ctx.strokeStyle = GRID; ctx.lineWidth = 1;
    for (let v = Math.ceil(x0 / step) * step; v <= x1; v += step) { ctx.beginPath(); ctx.moveTo(X(v), mt); ctx.lineTo(X(v), mt + h); ctx.stroke(); }
    for (let v = Math.ceil(y0 / step) * step; v <= y1; v += step) { ctx.beginPath(); ctx.moveTo(ml, Y(v)); ctx.lineTo(ml + w, Y(v)); ctx.stroke(); }
    ctx.setLineDash([4, 4]); ctx.strokeStyle = "#56606b";
    for (const p of state.plan || []) { ctx.beginPath(); ctx.moveTo(X(p[0]), Y(p[1])); ctx.lineTo(X(p[2]), Y(p[3])); ctx.stroke(); }
    ctx.setLineDash([]);
    ctx.strokeStyle = "#4aa3ff"; ctx.lineWidth = 2;
    for (const t of Object.values(state.tracks || {})) {
      ctx.beginPath(); t.forEach((p, i) => (i ? ctx.lineTo(X(p[0]), Y(p[1])) : ctx.moveTo(X(p[0]), Y(p[1])))); ctx.stroke();
    }
    ctx.fillStyle = "rgba(255,160,60,0.35)";
    for (const pts of Object.values(state.slices || {})) for (const p of pts) ctx.fillRect(X(p[0]) - 1, Y(p[1]) - 1, 2, 2);
    for (const pipe of state.pipes || []) {
      ctx.strokeStyle = pipe.colour || "#ff6"; ctx.lineWidth = Math.max(3, pipe.diameter_m * scale); ctx.lineCap = "round";
      ctx.beginPath(); pipe.axis_m.forEach((p, i) => (i ? ctx.lineTo(X(p[0]), Y(p[1])) : ctx.moveTo(X(p[0]), Y(p[1])))); ctx.stroke();
      const mid = pipe.axis_m[Math.floor(pipe.axis_m.length / 2)];
      ctx.fillStyle = "#fff"; ctx.font = "11px system-ui"; ctx.textAlign = "left";
      ctx.fillText(`#${pipe.id} cover ${(pipe.depth_of_cover_m * 100).toFixed(1)} cm`, X(mid[0]) + 6, Y(mid[1]) - 6);
    }
    ctx.lineWidth = 2;
    for (const dets of Object.values(state.detections || {})) for (const d of dets) {
      ctx.strokeStyle = "#ffd400"; ctx.beginPath(); ctx.arc(X(d.x_m), Y(d.y_m), 5, 0, 2 * Math.PI); ctx.stroke();
    }
    if (state.robot) { // the base (red dot, heading tick) and the antenna at the lever arm (red square)
      const r = state.robot, yaw = (r.yaw_deg || 0) * Math.PI / 180, arm = state.leverArm || [0, 0];
      const ax = r.x + Math.cos(yaw) * arm[0] - Math.sin(yaw) * arm[1], ay = r.y + Math.sin(yaw) * arm[0] + Math.cos(yaw) * arm[1];
      ctx.strokeStyle = "#ff4d4f"; ctx.beginPath(); ctx.moveTo(X(r.x), Y(r.y)); ctx.lineTo(X(ax), Y(ay)); ctx.stroke();
      ctx.fillStyle = "#ff4d4f"; ctx.beginPath(); ctx.arc(X(r.x), Y(r.y), 6, 0, 2 * Math.PI); ctx.fill();
      ctx.fillRect(X(ax) - 4, Y(ay) - 4, 8, 8);
    }
    ticks(ctx, ml, mt, w, h, [x0, x1], [y1, y0], "x (m)", "y (m)");
  }

  window.GprDraw = { b64bytes, b64int16, b64float32, lut, radargram, section, map, niceStep };
})();
