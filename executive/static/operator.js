// The operator page's logic: live state from /events (server-sent events), actions through the daemon's API,
// camera views with the perceived outlines and the chosen grasp, run history. Plain browser JavaScript.
"use strict";

const WORKING = ["scan", "perceive", "select_grasp", "plan", "execute", "verify", "recover"];
const TOKEN_KEY = "kitchenbot.token";
const $ = (id) => document.getElementById(id);

const ui = {
  status: { busy: false, state: "idle", homed: true, interrupted_runs: [] },
  connected: false,
  object: "",       // the object being worked on (progress events)
  lastEvent: "",
  perceptionKey: "",  // run:perception:grasp drawn now
};

// ---- the token: entered once, kept for this browser tab (sessionStorage) ------------------------------------------
function token() { return sessionStorage.getItem(TOKEN_KEY) || ""; }

function showToken() {
  $("token-state").textContent = token() ? "token set for this tab" : "no token: enter it to start, pause, resume or home";
  $("token").value = "";
  $("token").placeholder = token() ? "•••••• (set)" : "daemon token";
}

// ---- the API ----------------------------------------------------------------------------------------------------------
async function api(method, path, body, auth = true) {
  const headers = {};
  if (auth && token()) headers["Authorization"] = "Bearer " + token();
  if (body !== undefined) headers["Content-Type"] = "application/json";
  let res;
  try {
    res = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  } catch (e) {
    throw new Error(`${method} ${path}: the daemon cannot be reached (${e.message})`);
  }
  let data = null;
  try { data = await res.json(); } catch (e) { data = null; }
  if (!res.ok) {
    const detail = data && data.detail !== undefined ? (typeof data.detail === "string" ? data.detail
                                                                                         : JSON.stringify(data.detail))
                                                   : res.statusText;
    throw new Error(`${method} ${path}: ${res.status} ${detail}`);
  }
  return data;
}

function showError(msg) {
  $("api-ok").hidden = true;
  $("api-error").textContent = msg;
  $("api-error").hidden = !msg;
}

function showOk(msg) {
  showError("");
  $("api-ok").textContent = msg;
  $("api-ok").hidden = !msg;
}

async function act(label, fn) {
  try {
    const out = await fn();
    showOk(label(out));
  } catch (e) {
    showError(e.message);
  }
  await refreshStatus();
}

// ---- rendering the state ------------------------------------------------------------------------------------------
function render() {
  const s = ui.status;
  const state = s.state || "idle";
  $("state").textContent = state.replace("_", " ");
  $("state").dataset.state = state;
  $("task").textContent = s.task ? s.task : "";
  $("run-id").textContent = s.run_id ? `#${s.run_id}` + (s.status ? ` (${s.status})` : "") : "–";
  $("attempts").textContent = s.run_id ? `${s.attempts ?? 0} / ${s.recoveries ?? 0}` : "–";
  $("last-event").textContent = ui.lastEvent || "–";
  const done = s.objects_done ?? 0, total = Math.max(s.objects_total ?? 0, done);
  let prog = "no run yet";
  if (s.run_id) {
    if (!total) prog = s.busy ? "looking for objects…" : `placed ${done}`;
    else if (s.busy && done < total) prog = `object ${done + 1} of ${total}` + (ui.object ? ` (${ui.object})` : "") +
                                             ` · ${done} placed`;
    else prog = `placed ${done} of ${total}`;
  }
  $("progress").textContent = prog;
  $("bar-fill").style.width = total ? `${Math.round(100 * done / total)}%` : "0";
  const msg = s.last_error ? `error: ${s.last_error}` : (s.message || "");
  $("message").textContent = msg;
  $("message").hidden = !msg || s.busy;

  // the homing banner: after an interrupted run (crash, kill) or a run that ended away from a safe pose
  const interrupted = s.interrupted_runs || [];
  $("banner").hidden = s.homed !== false || s.busy;  // a run in progress has left home: that is no crash
  $("banner-text").textContent = interrupted.length
    ? interrupted.map((r) => `run ${r.id} (${r.task}) was interrupted`).join("; ") +
      ". The arm may be anywhere: home it before the next run."
    : "The last run did not end at a safe pose. Home the arm before the next run.";

  // every button says why it cannot act now
  const haveToken = !!token();
  const working = WORKING.includes(state);
  const setBtn = (id, why) => {
    $(id).disabled = !!why;
    $(id + "-why").textContent = why || "";
  };
  const offline = ui.connected ? "" : "no connection to the daemon";
  setBtn("start", offline || (s.busy ? `busy: run #${s.run_id} is ${state}` :
                              s.homed === false ? "homing required" : !haveToken ? "no token" : ""));
  setBtn("pause", offline || (!s.busy ? "nothing is running" : state === "paused" ? "already paused" :
                              !working ? `not while ${state}` : !haveToken ? "no token" : ""));
  setBtn("resume", offline || (!s.busy ? "nothing is running" : state !== "paused" ? "not paused" :
                               !haveToken ? "no token" : ""));
  setBtn("home", offline || (s.busy ? "busy: stop the run first" : !haveToken ? "no token" : ""));
  $("banner-home").disabled = !!(offline || s.busy || !haveToken);
  $("banner-home").title = !haveToken ? "no token" : "";
}

function describe(ev) {
  switch (ev.type) {
    case "transition": return `${ev.source} → ${ev.dest} (${ev.trigger})`;
    case "fault": return `fault ${ev.kind}: ${ev.message}`;
    case "placed": return `placed the ${ev.object}`;
    case "paused": return "paused";
    case "finished": return `finished: ${ev.status}`;
    case "error": return `error: ${ev.message}`;
    case "progress": return ev.object ? `next: the ${ev.object}` : `perceived: ${ev.objects_total ?? "?"} to do`;
    default: return ev.type;
  }
}

// ---- live events ------------------------------------------------------------------------------------------------
function connect() {
  const es = new EventSource("/events");
  const conn = $("conn");
  es.onopen = () => { ui.connected = true; conn.dataset.state = "open"; conn.textContent = "live"; render(); };
  es.onerror = () => {
    if (es.readyState === EventSource.CLOSED) setTimeout(connect, 1000);  // the browser gave up: start again
    ui.connected = false;
    $("api-ok").hidden = true;  // it was about an earlier action
    conn.dataset.state = "lost";
    conn.textContent = "connection lost: reconnecting…";
    render();
  };
  es.addEventListener("status", (m) => {
    const before = ui.status.run_id;
    ui.status = JSON.parse(m.data);
    if (!ui.status.busy) ui.object = "";
    if (ui.status.run_id !== before) ui.lastEvent = "";  // a new run, or a restarted daemon
    render();
    refreshImages();
    refreshHistory();
  });
  for (const type of ["transition", "progress", "placed", "fault", "paused", "finished", "error"]) {
    es.addEventListener(type, (m) => {
      const ev = JSON.parse(m.data);
      const s = ui.status;
      if (ev.objects_done !== undefined) s.objects_done = ev.objects_done;
      if (ev.objects_total !== undefined) s.objects_total = ev.objects_total;
      if (type === "transition") s.state = ev.dest;
      if (type === "paused") s.state = "paused";
      if (type === "progress" && ev.object) ui.object = ev.object;
      if (type === "error") s.last_error = ev.message;
      ui.lastEvent = describe(ev);
      render();
      if (type === "transition" && ["perceived", "planned", "next_object", "complete"].includes(ev.trigger)) {
        refreshImages();
      }
      if (type === "finished" || type === "placed") { refreshStatus(); refreshHistory(); }
    });
  }
}

async function refreshStatus() {
  try {
    ui.status = await api("GET", "/status", undefined, false);
    render();
  } catch (e) { /* the event stream reports the lost connection */ }
}

// ---- camera views with outlines and the grasp ------------------------------------------------------------------
const SVG = "http://www.w3.org/2000/svg";
function el(name, attrs, parent) {
  const e = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}

let imagesPending = false, imagesAgain = false;
async function refreshImages() {
  if (imagesPending) { imagesAgain = true; return; }  // fetched once more when the running fetch is done
  imagesPending = true;
  imagesAgain = false;
  try {
    const p = await api("GET", "/perception/latest", undefined, false);
    const key = `${p.run_id}:${p.seq}:${p.grasp ? p.grasp.xyz.join(",") : ""}`;
    if (key === ui.perceptionKey) return;
    ui.perceptionKey = key;
    const box = $("views");
    box.replaceChildren();
    if (!p.views.length) {
      box.innerHTML = '<p class="hint">no images yet</p>';
      $("camera-caption").textContent = "";
      return;
    }
    $("camera-caption").textContent = `run #${p.run_id}, perception ${p.seq}` +
      (p.grasp ? ` · grasp ${p.grasp.name} on the ${p.grasp.cls}` : "");
    for (const v of p.views) {
      const fig = document.createElement("figure");
      const cam = document.createElement("div");
      cam.className = "cam";
      const img = document.createElement("img");
      img.alt = `camera view ${v.index + 1}`;
      img.width = v.width;
      img.height = v.height;
      img.src = `/perception/latest/${v.index}.png?run=${p.run_id}&seq=${p.seq}`;
      cam.appendChild(img);
      const svg = el("svg", { viewBox: `0 0 ${v.width} ${v.height}`, preserveAspectRatio: "none" }, cam);
      for (const o of v.objects) {
        el("polygon", { points: o.outline.map((q) => q.join(",")).join(" "), class: o.selected ? "selected" : "" },
           svg);
        const top = o.outline.reduce((a, q) => (q[1] < a[1] ? q : a), o.outline[0]);
        const t = el("text", { x: top[0], y: Math.max(14, top[1] - 5), "text-anchor": "middle" }, svg);
        t.textContent = `${o.cls} ${o.score.toFixed(2)}`;
      }
      if (v.grasp) {
        const g = v.grasp;
        el("line", { x1: g.pregrasp[0], y1: g.pregrasp[1], x2: g.tcp[0], y2: g.tcp[1], class: "approach" }, svg);
        for (const [a, b] of g.fingers) el("line", { x1: a[0], y1: a[1], x2: b[0], y2: b[1], class: "finger" }, svg);
        el("circle", { cx: g.tcp[0], cy: g.tcp[1], r: 5, class: "tcp" }, svg);
      }
      fig.appendChild(cam);
      const cap = document.createElement("figcaption");
      const n = v.objects.length;
      cap.textContent = `view ${v.index + 1}: ${n} object${n === 1 ? "" : "s"}` + (v.grasp ? ", grasp shown" : "");
      fig.appendChild(cap);
      box.appendChild(fig);
    }
  } catch (e) { /* shown by the connection state */ }
  finally {
    imagesPending = false;
    if (imagesAgain) refreshImages();
  }
}

// ---- run history -------------------------------------------------------------------------------------------------
function text(tag, s, cls) { const e = document.createElement(tag); e.textContent = s; if (cls) e.className = cls; return e; }

async function refreshHistory() {
  let runs;
  try { runs = await api("GET", "/runs?limit=20", undefined, false); } catch (e) { return; }
  const body = $("runs");
  const open = new Set([...body.querySelectorAll("tr.report-row")].map((r) => r.dataset.run));
  body.replaceChildren();
  for (const r of runs) {
    const tr = document.createElement("tr");
    tr.className = "run";
    tr.dataset.run = r.id;
    tr.appendChild(text("td", `#${r.id}`));
    tr.appendChild(text("td", r.task));
    tr.appendChild(text("td", r.status, `status-${r.status}`));
    tr.appendChild(text("td", r.objects_done == null ? "–" : `${r.objects_done} / ${r.objects_total ?? "?"}`));
    tr.appendChild(text("td", new Date(r.started * 1000).toLocaleString(), "hide-narrow"));
    const msg = r.message || (r.status === "interrupted" ? "the daemon stopped during this run" : "");
    tr.appendChild(text("td", msg + (r.failures ? ` (${r.failures} failure${r.failures > 1 ? "s" : ""})` : "")));
    tr.title = "show the report";
    tr.addEventListener("click", () => toggleReport(tr, r.id));
    body.appendChild(tr);
    if (open.has(String(r.id))) toggleReport(tr, r.id);
  }
}

async function toggleReport(tr, id) {
  const next = tr.nextElementSibling;
  if (next && next.classList.contains("report-row")) { next.remove(); return; }
  const row = document.createElement("tr");
  row.className = "report-row";
  row.dataset.run = id;
  const td = document.createElement("td");
  td.colSpan = 6;
  td.className = "report";
  row.appendChild(td);
  tr.after(row);
  let run;
  try { run = await api("GET", `/runs/${id}`, undefined, false); } catch (e) { td.textContent = e.message; return; }
  const rep = run.report;
  const div = document.createElement("div");
  div.className = "report";
  if (!rep) {
    div.appendChild(text("p", run.status === "interrupted"
      ? "Interrupted: the daemon stopped during this run (crash or kill); no report was written."
      : `No report (${run.status}).`));
  } else {
    const dl = document.createElement("dl");
    const add = (k, v) => { if (v !== undefined && v !== null && v !== "") { dl.appendChild(text("dt", k)); dl.appendChild(text("dd", v)); } };
    add("status", rep.status);
    add("placed", `${rep.objects_done} of ${rep.objects_total}`);
    add("attempts / recoveries", `${rep.attempts} / ${rep.recoveries}`);
    add("perception", rep.perception);
    add("seed", rep.seed);
    if (rep.collisions !== null && rep.collisions !== undefined) add("collisions / limit violations", `${rep.collisions} / ${rep.limit_violations}`);
    add("wall time", rep.wall_time_s !== undefined ? `${rep.wall_time_s.toFixed(1)} s` : "");
    add("ended safe", rep.safe === false ? "no (homing required)" : "yes");
    add("message", rep.message);
    add("error", rep.error);
    div.appendChild(dl);
    const fails = rep.failures || [];
    div.appendChild(text("strong", fails.length ? `Failures (${fails.length})` : "No failures"));
    if (fails.length) {
      const ol = document.createElement("ol");
      for (const f of fails) ol.appendChild(text("li", `${f.kind} in ${f.state}: ${f.message}`));
      div.appendChild(ol);
    }
  }
  td.appendChild(div);
}

// ---- actions -----------------------------------------------------------------------------------------------------
async function stop() {
  // no token on purpose: stopping never moves the robot
  try {
    const out = await api("POST", "/stop", undefined, false);
    showOk(out.stopped ? `stopped (run #${out.run_id}, ${out.state})` : out.detail);
  } catch (e) {
    showError(`${e.message} — STOP did not reach the robot: use the emergency stop on the teach pendant`);
  }
  await refreshStatus();
}

function start() {
  const body = { task: $("task-select").value, oracle_perception: $("oracle").checked };
  const seed = $("seed").value.trim();
  if (seed !== "") body.seed = Number(seed);
  return act((o) => `started run #${o.run_id} (${o.task})`, () => api("POST", "/runs", body));
}

function home() { return act(() => "homed: motion allowed again", () => api("POST", "/home")); }

function init() {
  $("stop").addEventListener("click", stop);
  $("start").addEventListener("click", start);
  $("pause").addEventListener("click", () => act(() => "pausing at the next safe point", () => api("POST", "/pause")));
  $("resume").addEventListener("click", () => act(() => "resumed", () => api("POST", "/resume")));
  $("home").addEventListener("click", home);
  $("banner-home").addEventListener("click", home);
  $("history-refresh").addEventListener("click", refreshHistory);
  $("token-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const t = $("token").value.trim();
    if (t) sessionStorage.setItem(TOKEN_KEY, t);
    showToken();
    render();
  });
  $("token-forget").addEventListener("click", () => { sessionStorage.removeItem(TOKEN_KEY); showToken(); render(); });
  // Space stops, wherever the focus is on the page (and never presses the focused button instead).
  const isSpace = (e) => e.code === "Space" || e.key === " ";
  window.addEventListener("keydown", (e) => {
    if (!isSpace(e)) return;
    e.preventDefault();
    e.stopPropagation();
    if (!e.repeat) stop();
  }, true);
  window.addEventListener("keyup", (e) => { if (isSpace(e)) { e.preventDefault(); e.stopPropagation(); } }, true);
  showToken();
  render();
  refreshStatus();
  refreshHistory();
  connect();
}

init();
