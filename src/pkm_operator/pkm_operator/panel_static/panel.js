// The operator panel's page: draws the snapshots the server pushes over /ws and sends
// the operator's actions (pkm_bringup/panel.py lists them). No framework, no build step.
"use strict";

const $ = (id) => document.getElementById(id);
// the panel's token: in the URL pkm-panel printed, then kept by this tab (and taken out
// of the address bar, so that a screenshot or a shared link does not carry it)
const token = (() => {
  const params = new URLSearchParams(location.search);
  const given = params.get("token");
  if (given) {
    sessionStorage.setItem("pkm-panel-token", given);
    params.delete("token");
    history.replaceState(null, "", location.pathname + (params.toString() ? `?${params}` : "") + location.hash);
  }
  return given || sessionStorage.getItem("pkm-panel-token");
})();
const SETTINGS = ["strategy", "distribution", "bandwidth_hz", "damping_ratio", "integral_time_s"];
let ws = null, machine = null, last = null, received = 0, perSecond = 0, estopUrl = "";
// snapshots drawn on this connection, told to the server with each heartbeat: it sends
// only a few ahead of them, so a slow page skips snapshots instead of lagging behind
let seen = 0;

function connect() {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws` +
              (token ? `?token=${encodeURIComponent(token)}` : "");
  ws = new WebSocket(url);
  ws.onopen = () => { $("link").textContent = "connected"; };
  ws.onclose = () => { $("link").textContent = "disconnected: reconnecting"; setTimeout(connect, 1000); };
  ws.onmessage = (e) => {
    const m = JSON.parse(e.data);
    if (m.type === "hello") { seen = 0; hello(m); }
    else if (m.type === "snapshot") { received += 1; last = m; render(m); seen += 1; }
    else if (m.type === "result") { show(m); }
  };
}

function send(action) {
  if (ws && ws.readyState === WebSocket.OPEN) { ws.send(JSON.stringify(action)); return true; }
  show({ ok: false, action: action.type, message: "not connected to the panel server" });
  return false;
}

function show(result) {
  const el = $("message");
  el.textContent = `${result.ok ? "" : "REFUSED "}${result.action || ""}: ${result.message}`;
  el.className = "message " + (result.ok ? "ok" : "refused");
}

function hello(m) {
  machine = m.machine;
  estopUrl = m.estop_url || "";
  $("machine").textContent = `${machine.machine} (${machine.kind})` + (m.authorized ? "" : " · view only");
  const jog = $("jog");
  jog.innerHTML = "";
  for (const axis of machine.axes) {
    const row = document.createElement("div");
    row.innerHTML = `<b>${axis}</b> <button data-axis="${axis}" data-sign="-1" id="jog-${axis}-minus">−</button>` +
                    `<button data-axis="${axis}" data-sign="1" id="jog-${axis}-plus">+</button>`;
    jog.appendChild(row);
  }
  jog.querySelectorAll("button").forEach((b) => b.onclick = () => {
    let step = parseFloat($("jogstep").value) * parseFloat(b.dataset.sign);
    if (machine.angular.includes(b.dataset.axis)) step *= 10;   // 1 mm of the step list = 10 mrad
    send({ type: "jog", axis: b.dataset.axis, step: step });
  });
  fill($("set-strategy"), machine.strategies);
  fill($("set-distribution"), machine.distributions);
  if (machine.kind !== "planar") { $("view").value = "xz"; }
}

function fill(select, names) {
  select.innerHTML = names.map((n) => `<option>${n}</option>`).join("");
}

const fmt = (v, k = 1) => (v === null || v === undefined || Number.isNaN(v)) ? "–" : (v * k).toFixed(3);

function render(s) {
  const c = s.controller || {}, v = c.values || {};
  let mode = v.mode || (s.estop && s.estop.latched ? "stopped" : "–");
  if (s.silent_s === null || s.silent_s > 1.0) mode = s.silent_s === null ? "waiting for the graph" :
                                                       `graph silent ${s.silent_s.toFixed(0)} s`;
  $("mode").textContent = mode;
  $("simtime").textContent = s.t_s !== undefined ? s.t_s.toFixed(3) : "–";
  $("mode").className = "badge " + mode;
  $("feedstate").textContent = `feed ${Math.round(100 * (v.feed_scale ?? 1))} %`;
  $("estopbar").hidden = !(s.estop && s.estop.latched);
  $("estopwhy").textContent = s.estop ? `${s.estop.why} · controller: ${c.message || "–"}` : "";
  $("reset").disabled = !(s.estop && s.estop.can_reset);
  $("strategy").textContent = v.strategy || "–";
  $("model").textContent = v.model || "–";
  $("distribution").textContent = v.distribution || "–";
  $("internal").textContent = v.internal_force_norm_n !== undefined ? Number(v.internal_force_norm_n).toFixed(1) : "–";
  // a setting the operator has edited is not overwritten until applied: a snapshot drawn
  // between the click's mousedown (the input loses focus) and its click event would
  // otherwise put the running value back and apply nothing
  for (const name of SETTINGS) {
    const input = $("set-" + name);
    if (document.activeElement !== input && v[name] !== undefined && !input.dataset.touched) input.value = v[name];
  }
  if (document.activeElement !== $("feed") && v.feed_override !== undefined) {
    $("feed").value = Math.round(100 * v.feed_override); $("feedvalue").textContent = $("feed").value;
  }
  const axes = machine ? machine.axes : ["x", "y", "z"];
  $("pose").tBodies[0].innerHTML = axes.map((a, i) => {
    const angle = machine && machine.angular.includes(a);
    const k = angle ? 1 : 1000, unit = angle ? "rad" : "mm";
    return `<tr><td>${a} ${unit}</td><td id="pose-${a}">${s.pose ? fmt(s.pose[i], k) : "–"}</td>` +
           `<td id="ref-${a}">${s.reference ? fmt(s.reference[i], k) : "–"}</td></tr>`;
  }).join("");
  if (s.drives) {
    $("drives").tBodies[0].innerHTML = s.drives.names.map((n, i) =>
      `<tr><td>${n}</td><td id="drive-${n}">${fmt(s.drives.position[i], 1000)}</td>` +
      `<td>${s.drives.effort[i].toFixed(1)}</td></tr>`).join("");
  }
  const servo = Object.entries(s.cia402 || {});
  $("servo").hidden = servo.length === 0;
  $("cia402").tBodies[0].innerHTML = servo.map(([n, d]) =>
    `<tr class="${d.level >= 2 ? "refused" : ""}"><td>${n}</td><td>${d.node_id}</td>` +
    `<td id="cia402-${n}">${d.state}</td><td>${d.statusword}</td><td>${d.error}</td><td>${d.homing}</td></tr>`)
    .join("");
  $("diagnostics").innerHTML = Object.entries(s.diagnostics || {}).map(([k, [lvl, msg]]) =>
    `<li class="${lvl >= 2 ? "refused" : ""}">${k}: ${msg}</li>`).join("");
  $("actions").innerHTML = (s.actions || []).slice().reverse().map((a) =>
    `<li class="${a.ok ? "" : "refused"}">${a.type}: ${a.message}</li>`).join("");
  $("loaded").textContent = s.program ? `${s.program.name}: ${s.program.moves} moves` : "";
  $("latency").textContent = Object.entries(s.latency_ms || {}).map(([k, ms]) => `${k} ${ms.toFixed(1)} ms`)
                               .join(" · ") || "–";
  const plot = s.plot || [];
  $("error").textContent = plot.length ? plot[plot.length - 1][1].toFixed(1) : "–";
  drawPlot(plot);
  drawScene(s);
}

function drawPlot(points) {
  const cv = $("plot"), g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  if (points.length < 2) return;
  const t0 = points[0][0], t1 = points[points.length - 1][0];
  const top = Math.max(1, ...points.map((p) => p[1])) * 1.1;
  g.strokeStyle = "#37a"; g.beginPath();
  points.forEach(([t, e], i) => {
    const x = (t - t0) / Math.max(t1 - t0, 1e-9) * (cv.width - 10) + 5, y = cv.height - 5 - e / top * (cv.height - 20);
    i ? g.lineTo(x, y) : g.moveTo(x, y);
  });
  g.stroke();
  g.fillStyle = "#555"; g.fillText(`${top.toFixed(0)} µm`, 5, 12); g.fillText(`${(t1 - t0).toFixed(1)} s`, cv.width - 40, cv.height - 8);
}

function drawScene(s) {
  const svg = $("scene");
  if (!s.drawing || !machine) return;
  const [i, j] = $("view").value === "xz" ? [0, 2] : [0, 1];
  const d = s.drawing, pts = [];
  for (const [a, b] of d.legs.concat(d.struts)) { pts.push(a, b); }
  if (!pts.length) return;
  const xs = pts.map((p) => p[i]), ys = pts.map((p) => p[j]);
  const lo = [Math.min(...xs), Math.min(...ys)], hi = [Math.max(...xs), Math.max(...ys)];
  const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-3) * 1.15;
  const cx = (lo[0] + hi[0]) / 2, cy = (lo[1] + hi[1]) / 2, scale = 440 / span;
  const X = (p) => (300 + (p[i] - cx) * scale).toFixed(1), Y = (p) => (240 - (p[j] - cy) * scale).toFixed(1);
  const line = (a, b, cls) => `<line x1="${X(a)}" y1="${Y(a)}" x2="${X(b)}" y2="${Y(b)}" class="${cls}"/>`;
  let out = "<style>.leg{stroke:#37a;stroke-width:4}.strut{stroke:#c80;stroke-width:1.5;stroke-dasharray:4 3}" +
            ".plat{fill:#9bd;fill-opacity:.5;stroke:#246}.ref{fill:none;stroke:#d33;stroke-width:2}" +
            ".tool{fill:#222}</style>";
  out += d.legs.map(([a, b]) => line(a, b, "leg")).join("");
  out += d.legs.map(([a]) => `<rect x="${X(a) - 5}" y="${Y(a) - 5}" width="10" height="10" fill="#444"/>`).join("");
  if (d.platform.length > 2) out += `<polygon class="plat" points="${d.platform.map((p) => `${X(p)},${Y(p)}`).join(" ")}"/>`;
  out += d.struts.map(([a, b]) => line(a, b, "strut")).join("");
  const pos = (p) => (machine.kind === "planar" ? [p[0], p[1], 0] : p);
  if (s.pose) out += `<circle class="tool" cx="${X(pos(s.pose))}" cy="${Y(pos(s.pose))}" r="4"/>`;
  if (s.reference) out += `<circle class="ref" cx="${X(pos(s.reference))}" cy="${Y(pos(s.reference))}" r="8"/>`;
  svg.innerHTML = out;
}

function estop() {
  // three ways: the socket, the main server's route, and the E-stop's own server (its
  // own thread and loop: it answers when the main server is stuck)
  if (estopUrl) fetch(estopUrl, { method: "POST", mode: "no-cors" }).catch(() => {});
  fetch("/api/estop", { method: "POST" }).catch(() => {});
  send({ type: "estop" });
}

$("estop").onclick = estop;
$("reset").onclick = () => send({ type: "reset" });
$("file").onchange = async (e) => {
  const f = e.target.files[0];
  if (!f) return;
  $("program").value = await f.text();
  $("program").dataset.name = f.name;
  send({ type: "program", text: $("program").value, name: f.name });
};
$("load").onclick = () => send({ type: "program", text: $("program").value, name: $("program").dataset.name || "program" });
$("start").onclick = () => send({ type: "start" });
$("feed").oninput = () => { $("feedvalue").textContent = $("feed").value; };
$("feed").onchange = () => send({ type: "feed", percent: Number($("feed").value) });
$("hold").onclick = () => send({ type: "feed", percent: 0 });
$("resume").onclick = () => send({ type: "feed", percent: 100 });
for (const name of SETTINGS) {
  $("set-" + name).onchange = $("set-" + name).oninput = (e) => { e.target.dataset.touched = "1"; };
}
$("apply").onclick = () => {
  const v = (last && last.controller && last.controller.values) || {}, changes = {};
  for (const name of ["strategy", "distribution"]) if ($("set-" + name).value !== v[name]) changes[name] = $("set-" + name).value;
  for (const name of ["bandwidth_hz", "damping_ratio", "integral_time_s"]) {
    const x = Number($("set-" + name).value);
    if ($("set-" + name).value !== "" && x !== v[name]) changes[name] = x;
  }
  for (const name of SETTINGS) delete $("set-" + name).dataset.touched;
  send({ type: "settings", changes: changes });
};
$("projection").onclick = () => {
  const current = last && last.controller && last.controller.values && last.controller.values.strategy;
  const other = { joint_pid: "decentralized_projected", decentralized_projected: "joint_pid" }[current];
  if (!other) { show({ ok: false, action: "projection", message: `projection: needs joint_pid or decentralized_projected, running ${current}` }); return; }
  send({ type: "settings", changes: { strategy: other } });
};
$("view").onchange = () => last && drawScene(last);
setInterval(() => { perSecond = received; received = 0; $("rate").textContent = perSecond; }, 1000);
setInterval(() => { if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: "heartbeat", seen: seen })); }, 100);
window.panelRate = () => perSecond;
connect();
