// gprbot console: the live socket (status, radargram, lines, map), control (e-stop, jog with dead-man,
// survey), and the Results tab. Commands are the shell's own lines, sent over the socket.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const csrf = document.querySelector('meta[name="gprbot-csrf"]').content;
  const state = { hello: null, run: null, line: null, lines: {}, map: { tracks: {}, detections: {}, slices: {}, pipes: [] },
                  velocity: null, status: null, estopped: false };
  window.gprConsole = state;  // for the browser tests and the curious operator
  let ws = null, nextId = 1, lastMessageT = 0;
  const pending = new Map();

  // ----- log ------------------------------------------------------------------------------------
  function log(text, cls) {
    const line = document.createElement("div");
    line.textContent = `${new Date().toLocaleTimeString()} ${text}`;
    if (cls) line.className = cls;
    const box = $("log"); box.append(line);
    while (box.childElementCount > 200) box.firstChild.remove();
    box.scrollTop = box.scrollHeight;
  }

  // ----- the socket -----------------------------------------------------------------------------
  function connect() {
    ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
    $("link").textContent = "socket connecting"; $("link").className = "pill warn";
    ws.onopen = () => { $("link").textContent = "socket live"; $("link").className = "pill ok"; };
    ws.onclose = () => {
      $("link").textContent = "socket lost — reconnecting"; $("link").className = "pill bad";
      stopJog(false);
      for (const [, p] of pending) p({ ok: false, code: "internal", text: "socket closed" });
      pending.clear();
      setTimeout(connect, 1000);
    };
    ws.onmessage = (event) => { lastMessageT = performance.now(); handle(JSON.parse(event.data)); };
  }
  // a quiet socket (no status for 2 s) counts as lost: the jog stops and the page says so
  setInterval(() => {
    if (ws && ws.readyState === WebSocket.OPEN && performance.now() - lastMessageT > 2000) {
      $("link").textContent = "socket quiet"; $("link").className = "pill bad"; stopJog(false);
    }
  }, 500);

  function send(cmd) {
    return new Promise((resolve) => {
      if (!ws || ws.readyState !== WebSocket.OPEN) { resolve({ ok: false, code: "internal", text: "not connected" }); return; }
      const id = nextId++;
      pending.set(id, resolve);
      ws.send(JSON.stringify({ id, cmd }));
    });
  }
  async function command(cmd, quiet) {
    const reply = await send(cmd);
    if (!quiet || !reply.ok) log(`${cmd} → ${reply.ok ? "ok" : "error " + reply.code} ${reply.text}`, reply.ok ? "okc" : "err");
    return reply;
  }

  function handle(m) {
    if (m.type === "reply") { const p = pending.get(m.id); pending.delete(m.id); if (p) p(m); return; }
    if (m.type === "hello") { state.hello = m; state.map.leverArm = m.lever_arm_m; fillSurveyForm(m.survey, m.jog); return; }
    if (m.type === "status") { showStatus(m); return; }
    if (m.type === "event") { log(`* ${m.text}`); return; }
    if (m.type === "run") { newRun(m); return; }
    if (m.type === "traces") { addTraces(m); return; }
    if (m.type === "line") { lineDone(m); return; }
    if (m.type === "survey_end") { surveyEnd(m); }
  }

  // ----- status ---------------------------------------------------------------------------------
  function showStatus(s) {
    state.status = s; state.estopped = s.estop;
    const mode = $("mode");
    mode.textContent = s.estop ? "E-STOP LATCHED" : s.mode; mode.className = "pill " + (s.estop ? "bad" : s.mode === "idle" ? "" : "ok");
    $("estop").classList.toggle("latched", s.estop);
    const rows = [];
    if (s.pose) rows.push(["pose", `x ${s.pose.x.toFixed(3)}  y ${s.pose.y.toFixed(3)} m`], ["heading", `${s.heading_deg.toFixed(2)}°`]);
    else rows.push(["pose", "filter initialising"]);
    rows.push(["speed", `${s.speed_m_s.toFixed(3)} m/s`]);
    if (s.survey) {
      const sv = s.survey;
      rows.push(["survey", `${sv.name} ${sv.state}`], ["progress", `line ${Math.max(sv.line + 1, 0)}/${sv.lines}, ${sv.lines_done} done, ${sv.traces} traces`]);
      if (sv.pipes != null) rows.push(["pipes", String(sv.pipes)]);
      if (sv.error) rows.push(["error", sv.error]);
    } else rows.push(["survey", "none"]);
    if (s.disk) rows.push(["disk left", `${s.disk.free_gb.toFixed(1)} of ${s.disk.total_gb.toFixed(0)} GB`]);
    rows.push(["recording", s.recording ? "yes" : "no"], ["daemon", s.healthy === false ? "UNHEALTHY" : "healthy"], ["browsers", String(s.clients)]);
    $("status").replaceChildren(...rows.flatMap(([k, v]) => [GprResults.el("dt", { text: k }), GprResults.el("dd", { text: v })]));
    const items = s.devices.map((d) => GprResults.el("li", {}, GprResults.el("span", { class: "dot" + (d.ok ? " ok" : "") }), `${d.name}: ${d.detail}`));
    const troubled = s.tasks.filter((t) => t.state !== "running");
    for (const t of troubled) items.push(GprResults.el("li", { class: "err" }, `task ${t.name} ${t.state} (restarts ${t.restarts})`));
    $("devices").replaceChildren(...items);
    if (s.pose) { state.map.robot = s.pose; drawMap(); }
  }

  // ----- the survey: radargram, lines, map ------------------------------------------------------
  function planOf(sv) {
    const plan = [];
    for (let i = 0; i < sv.lines; i++) {
      const y = sv.start_xy_m[1] + i * sv.spacing_m;
      plan.push([sv.start_xy_m[0], y, sv.start_xy_m[0] + sv.length_m, y]);
    }
    return plan;
  }
  function newRun(m) {
    state.run = m.run; state.line = null; state.lines = {};
    state.lineLength = m.survey.length_m;
    state.map = { tracks: {}, detections: {}, slices: {}, pipes: [], plan: planOf(m.survey), robot: state.map.robot,
                  leverArm: state.map.leverArm,
                  area: [m.survey.start_xy_m[0], m.survey.start_xy_m[0] + m.survey.length_m, m.survey.start_xy_m[1],
                         m.survey.start_xy_m[1] + (m.survey.lines - 1) * m.survey.spacing_m] };
    $("sections").replaceChildren(); drawMap(); drawRadargram();
  }
  function addTraces(m) {
    let line = state.lines[m.line];
    if (!line) {
      line = state.lines[m.line] = { line: m.line, columns: [], samples: m.samples, dt_ns: m.dt_ns, t0_ns: m.t0_ns };
    }
    state.line = m.line;
    const counts = GprDraw.b64int16(m.data);
    for (let j = 0; j < m.n; j++) {
      const values = new Float32Array(m.samples);
      for (let k = 0; k < m.samples; k++) values[k] = counts[j * m.samples + k] * m.scale;
      line.columns.push({ values, x_m: m.x_m[j] });
    }
    const n = line.columns.length;
    if (n > 1) line.metresPerTrace = Math.max(1e-4, (line.columns[n - 1].x_m - line.columns[0].x_m) / (n - 1));
    $("rg-title").textContent = `line ${m.line} (${line.columns.length} traces)`;
    drawRadargram();
  }
  function lineDone(m) {
    state.map.tracks[m.line] = m.track;
    if (m.detections) state.map.detections[m.line] = m.detections;
    if (m.slice_xyz) state.map.slices[m.line] = m.slice_xyz;
    if (m.section) {
      state.velocity = m.section.velocity_m_per_ns;
      const card = document.createElement("div"); card.className = "section-card"; card.id = `section-${m.line}`;
      const canvas = document.createElement("canvas"); canvas.width = 340; canvas.height = 190;
      GprDraw.section(canvas, m.section, m.detections);
      const cap = document.createElement("div"); cap.className = "cap";
      cap.textContent = `line ${m.line}: ${m.detections.length} detection(s), v = ${m.section.velocity_m_per_ns.toFixed(3)} m/ns (${m.section.velocity_source})`;
      card.append(canvas, cap);
      const old = $(`section-${m.line}`); if (old) old.replaceWith(card); else $("sections").append(card);
    }
    drawMap();
  }
  async function surveyEnd(m) {
    log(`survey ${m.run} ${m.state}${m.pipes != null ? ", " + m.pipes + " pipes" : ""}${m.error ? ": " + m.error : ""}`, m.state === "failed" ? "err" : "okc");
    const doc = await fetchJson(`/api/runs/${encodeURIComponent(m.run)}`);
    if (doc && doc.pipes && doc.pipes.pipes) { state.map.pipes = doc.pipes.pipes; drawMap(); }
    refreshRuns(m.run);
  }
  function radargramOptions() {
    return { gainDb: +$("gain").value, tpow: +$("tpow").value, cmap: $("cmap").value, background: $("bgrem").checked,
             dewow: $("dewow").checked, frequency_mhz: state.hello ? state.hello.gpr.frequency_mhz : 900,
             velocity: state.velocity, lineLength_m: state.lineLength };
  }
  let drawQueued = false;
  function drawRadargram() {
    if (drawQueued) return; drawQueued = true;
    requestAnimationFrame(() => { drawQueued = false; state.drawn = GprDraw.radargram($("radargram"), state.lines[state.line], radargramOptions()).drawn; });
  }
  function drawMap() { GprDraw.map($("map"), state.map); }
  for (const id of ["gain", "tpow", "cmap", "bgrem", "dewow"]) $(id).addEventListener("input", () => {
    $("gain-v").textContent = `${$("gain").value} dB`; $("tpow-v").textContent = $("tpow").value; drawRadargram();
  });

  // ----- e-stop and reset -------------------------------------------------------------------------
  async function estop(event) {
    state.estopClickedAt = performance.timeOrigin + performance.now();  // epoch ms, for the latency test
    if (event) event.preventDefault();
    stopJog(false);
    if (ws && ws.readyState === WebSocket.OPEN) { const r = await command("estop"); if (r.ok) return; }
    // no socket: the plain HTTP path (no login needed, like the shell's estop)
    const r = await fetch("/api/estop", { method: "POST", keepalive: true, headers: { [CSRF]: csrf } }).catch((e) => null);
    log(r && r.ok ? "estop sent over HTTP" : "ESTOP NOT CONFIRMED — use the robot's hardware e-stop", r && r.ok ? "okc" : "err");
  }
  const CSRF = "X-Gprbot-CSRF";
  $("estop").addEventListener("pointerdown", estop);  // on press, not on release
  $("estop").addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") estop(e); });
  $("reset").addEventListener("click", () => command("reset"));

  // ----- jog with a dead-man: commands repeat while held; release, blur or a hidden page stops -----
  let jogTimer = null, jogButton = null;
  function jogOnce(dir) {
    const v = +$("jog-speed").value;
    send(`jog ${(dir[0] * v).toFixed(3)} ${(dir[1] * v).toFixed(3)} 0.4`).then((r) => { if (!r.ok) { log(`jog refused: ${r.code} ${r.text}`, "err"); stopJog(false); } });
  }
  function startJog(dir, button) {
    if (jogTimer) stopJog(false);
    jogButton = button; if (button) button.classList.add("held");
    jogOnce(dir); jogTimer = setInterval(() => jogOnce(dir), 100);
  }
  function stopJog(sendStop = true) {
    if (!jogTimer) return;
    clearInterval(jogTimer); jogTimer = null;
    if (jogButton) jogButton.classList.remove("held"); jogButton = null;
    if (sendStop) send("stop");
  }
  for (const button of document.querySelectorAll("[data-jog]")) {
    const dir = button.dataset.jog.split(",").map(Number);
    button.addEventListener("pointerdown", (e) => { e.preventDefault(); button.setPointerCapture(e.pointerId); startJog(dir, button); });
    for (const ev of ["pointerup", "pointercancel", "lostpointercapture"]) button.addEventListener(ev, () => stopJog());
  }
  const KEYS = { ArrowUp: [1, 0], ArrowDown: [-1, 0], ArrowLeft: [0, 1], ArrowRight: [0, -1] };
  let heldKey = null;
  document.addEventListener("keydown", (e) => {
    if (e.key === "Escape") { estop(e); return; }
    if (!KEYS[e.key] || e.target.tagName === "INPUT" || e.target.tagName === "SELECT") return;
    e.preventDefault();
    if (e.repeat || heldKey === e.key) return;
    heldKey = e.key; startJog(KEYS[e.key], null);
  });
  document.addEventListener("keyup", (e) => { if (e.key === heldKey) { heldKey = null; stopJog(); } });
  window.addEventListener("blur", () => { heldKey = null; stopJog(); });
  document.addEventListener("visibilitychange", () => { if (document.hidden) { heldKey = null; stopJog(); } });
  $("stop").addEventListener("click", () => { stopJog(false); command("stop"); });
  $("jog-speed").addEventListener("input", () => { $("jog-speed-v").textContent = `${(+$("jog-speed").value).toFixed(2)} m/s`; });

  // ----- survey -----------------------------------------------------------------------------------
  function fillSurveyForm(sv, jog) {
    $("s-lines").value = sv.lines; $("s-spacing").value = sv.spacing_m; $("s-length").value = sv.length_m;
    $("s-speed").value = sv.speed_m_s; $("s-speed").max = jog.max_speed_m_s; $("jog-speed").max = jog.max_speed_m_s;
  }
  function surveyLine() {
    const fields = [["lines", "s-lines"], ["spacing", "s-spacing"], ["length", "s-length"], ["speed", "s-speed"]];
    const problems = [];
    for (const [, id] of fields) {
      const input = $(id);
      if (!input.checkValidity() || (id === "s-lines" && !Number.isInteger(+input.value)))
        problems.push(`${input.labels[0].textContent} must be ${id === "s-lines" ? "a whole number " : ""}in [${input.min}, ${input.max}]`);
    }
    $("form-error").textContent = problems.join("; ");
    return problems.length ? null : "survey start " + fields.map(([k, id]) => `${k}=${+$(id).value}`).join(" ");
  }
  $("survey-start").addEventListener("click", () => { const line = surveyLine(); if (line) command(line); });
  $("survey-pause").addEventListener("click", () => command("survey pause"));
  $("survey-resume").addEventListener("click", () => command("survey resume"));
  $("survey-abort").addEventListener("click", () => command("survey abort"));

  // ----- results ----------------------------------------------------------------------------------
  async function fetchJson(url) {
    const r = await fetch(url, { credentials: "same-origin" });
    if (!r.ok) { log(`${url}: HTTP ${r.status}`, "err"); return null; }
    return r.json();
  }
  async function refreshRuns(select) {
    const list = await fetchJson("/api/runs");
    if (!list) return;
    const sel = $("run-select"), current = select || sel.value;
    sel.replaceChildren(...list.runs.map((r) => GprResults.el("option", { value: r, text: r })));
    if (current && list.runs.includes(current)) sel.value = current;
    if (!$("tab-results").hidden) showRun(sel.value);
  }
  let three = null;
  const loadThree = () => (three = three || import("/static/vendor/three-0.170.0.module.min.js"));
  async function showRun(run) {
    if (!run) return;
    const doc = await fetchJson(`/api/runs/${encodeURIComponent(run)}`);
    if (!doc) return;
    const base = `/runs/${encodeURIComponent(run)}/`;
    $("report-link").href = base + "report.html";
    GprResults.render($("results"), doc, { url: (n) => base + encodeURI(n) + "?download=1", picture: (n) => base + encodeURI(n), loadThree });
  }
  $("run-select").addEventListener("change", () => showRun($("run-select").value));
  $("run-refresh").addEventListener("click", () => refreshRuns());
  for (const tab of document.querySelectorAll("button.tab")) tab.addEventListener("click", () => {
    for (const t of document.querySelectorAll("button.tab")) t.classList.toggle("active", t === tab);
    $("tab-live").hidden = tab.dataset.tab !== "live"; $("tab-results").hidden = tab.dataset.tab !== "results";
    if (tab.dataset.tab === "results") refreshRuns();
  });

  state.command = command;  // the page's own command path, for the browser tests
  drawMap(); drawRadargram(); connect(); refreshRuns();
})();
