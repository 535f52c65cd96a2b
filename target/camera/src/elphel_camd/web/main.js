// The page: ports, live view (MJPEG over fetch, so the token can be sent), window drawn on
// the picture, the parameter form, capture, the event log and the quad overview.

import { API, NeedsToken, events, json, multipart, request, setToken, token } from "./api.js";
import { ParamForm, loadSchema } from "./controls.js";

const $ = (id) => document.getElementById(id);
const state = {
  port: 0,
  info: null,
  schema: null,
  params: {},
  stream: null,
  quad: null,
  readsPublic: false,
  token: "none",
};

const form = new ParamForm($("param-form"), $("readonly"), async (changes) => {
  const query = {};
  if (document.querySelector('input[name="when"]:checked').value === "ahead") {
    query.ahead = $("ahead").value || "0";
  }
  const answer = await json(`/ports/${state.port}/params`, { method: "PATCH", body: changes, query });
  state.params = answer.params;
  return answer;
});

// A 401 while a token is set: the camera no longer takes it (its token changed).
function showError(where, e) {
  if (e instanceof NeedsToken && token()) refuseToken();
  if (e instanceof NeedsToken) where.textContent = state.token === "refused" ? "token refused" : "needs the token";
  else where.textContent = e.message;
}

// -- token --------------------------------------------------------------------------------
// Whether reads need the token comes from the daemon's OpenAPI contract (open, and its
// read operations carry no security when reads are public). A token is checked before it
// is trusted, and reads that would answer 401 are not sent at all.

const TOKEN_STATE = {
  none: "no token",
  checking: "checking the token…",
  accepted: "token accepted",
  refused: "token refused",
  unchecked: "token not checked",
};
const TOKEN_PANEL = {
  none: "needs the token: enter it above to change parameters",
  checking: "checking the token…",
  refused: "token refused: the camera does not accept it; enter the right one above",
};

function showToken(name, detail) {
  state.token = name;
  const ok = name === "accepted";
  $("token-state").textContent = TOKEN_STATE[name];
  $("token-state").dataset.state = name;
  $("needs-token").hidden = ok;
  $("needs-token").textContent = detail || TOKEN_PANEL[name] || "";
  $("param-form").disabled = !ok;
  $("capture-form").disabled = !ok;
}

function refuseToken() {
  setToken(""); // a refused token is not sent again
  showToken("refused");
}

const canRead = () => state.readsPublic || state.token === "accepted";

async function readsArePublic() {
  try {
    const contract = await (await fetch("/openapi.json")).json();
    return !contract.paths[`${API}/info`].get.security;
  } catch {
    return false; // not known: ask for the token rather than send reads that need it
  }
}

// Reads that need the token prove it when reads are protected; otherwise a change that
// changes nothing (an empty PATCH of a port's parameters) does. Answers [state, detail].
async function checkToken() {
  try {
    state.info = await json("/info");
    if (state.readsPublic) {
      const ports = sensorPorts();
      const port = ports.includes(state.port) ? state.port : ports[0];
      await json(`/ports/${port}/params`, { method: "PATCH", body: {} });
    }
    return ["accepted"];
  } catch (e) {
    if (e instanceof NeedsToken) return ["refused"];
    return ["unchecked", `token not checked: ${e.message}`];
  }
}

// The newest token wins: a check that a newer one overtook shows nothing.
const readsLearned = readsArePublic().then((open) => (state.readsPublic = open));
let checks = 0;

async function tokenChanged() {
  const mine = ++checks;
  await readsLearned;
  if (token()) showToken("checking");
  const [name, detail] = token() ? await checkToken() : ["none"];
  if (mine !== checks) return;
  if (name === "refused") refuseToken();
  else showToken(name, detail);
  if (canRead()) reconnect();
  else shutOut();
}

$("token-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  setToken($("token").value.trim());
  $("token").value = "";
  tokenChanged();
});
$("token-clear").addEventListener("click", () => {
  setToken("");
  tokenChanged();
});

// A new token: reads that needed one may work now. The form stays as it is (a message
// next to a field stays readable); streams are reopened with the new token.
function reconnect() {
  if (!state.info || !state.schema) {
    restart();
    return;
  }
  if (!state.quad) liveView(state.port);
  eventLog();
}

// Reads need a token the page does not have: nothing is read until one is accepted.
function shutOut() {
  stopStream();
  if (eventsAbort) eventsAbort.abort();
  state.quad = null;
  $("view-error").textContent = state.token === "refused" ? "token refused" : "needs the token";
}

// -- live view ----------------------------------------------------------------------------

function stopStream() {
  if (state.stream) state.stream.abort();
  state.stream = null;
}

async function liveView(port) {
  stopStream();
  const controller = new AbortController();
  state.stream = controller;
  const img = $("live");
  img.dataset.port = String(port);
  // Reopened after a failure (a daemon restart, a frame that did not come) until the
  // view is closed or the port changes; a missing token waits for the token instead.
  while (state.stream === controller) {
    try {
      await streamInto(img, port, controller.signal);
    } catch (e) {
      if (e.name === "AbortError") return;
      showError($("view-error"), e);
      if (e instanceof NeedsToken) return;
    }
    await new Promise((r) => setTimeout(r, 2000));
  }
}

// The largest reduction that keeps the preview at least 640 px wide (1/8 at most).
function scaleFor(width) {
  let factor = 1;
  while (factor < 8 && width / (factor * 2) >= 640) factor *= 2;
  return factor;
}

async function streamInto(img, port, signal) {
  const factor = scaleFor(state.params.WOI_WIDTH || 640);
  img.dataset.scale = String(factor);
  const answer = await request(`/ports/${port}/preview.mjpeg`, {
    query: { scale: `1/${factor}`, fps: "10" },
    signal,
  });
  $("view-error").textContent = "";
  let shown = 0;
  const started = performance.now();
  for await (const part of multipart(answer)) {
    const url = URL.createObjectURL(new Blob([part.body], { type: "image/jpeg" }));
    const old = img.src;
    img.src = url;
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    const frame = Number(part.headers["x-frame-number"]);
    img.dataset.frame = String(frame);
    img.dataset.timestampNs = part.headers["x-timestamp-ns"];
    img.dataset.width = part.headers["x-image-width"];
    img.dataset.height = part.headers["x-image-height"];
    shown += 1;
    $("live-frame").textContent = String(frame);
    $("live-time").textContent = timeOf(part.headers["x-timestamp-ns"]);
    $("live-fps").textContent = (shown / ((performance.now() - started) / 1000)).toFixed(1);
    $("live-size").textContent = `${img.dataset.width}×${img.dataset.height}`;
    thermal(part.headers);
    form.reached(frame);
    state.frame = frame;
  }
}

function timeOf(ns) {
  const ms = Number(BigInt(ns) / 1000000n);
  return `${new Date(ms).toISOString().slice(11, 23)} (${ns} ns)`;
}

function thermal(headers) {
  const low = headers["x-temperature-min-c"];
  $("thermal").hidden = low === undefined;
  if (low === undefined) return;
  $("t-low").textContent = `${Number(low).toFixed(1)} °C`;
  $("t-high").textContent = `${Number(headers["x-temperature-max-c"]).toFixed(1)} °C`;
  const stops = headers["x-palette"].split(",");
  // A CSP-safe gradient: one span per stop (no inline styles needed beyond the DOM API).
  const bar = $("t-bar");
  if (bar.childElementCount !== stops.length) {
    bar.replaceChildren(...stops.map(() => document.createElement("i")));
  }
  [...bar.children].forEach((i, k) => (i.style.background = stops[k]));
}

// -- histogram ----------------------------------------------------------------------------

async function histogramLoop() {
  for (;;) {
    await new Promise((r) => setTimeout(r, 1500));
    if (state.quad || state.frame === undefined || !canRead()) continue;
    try {
      // the newest frame's (its number is in the caption): the one on view may have left
      // the ring buffer by the time this asks, when the view lags behind the sensor
      drawHistogram(await json(`/ports/${state.port}/histogram`));
    } catch (e) {
      $("hist-text").textContent = e instanceof NeedsToken ? "histogram: needs the token" : `histogram: ${e.message}`;
    }
  }
}

function drawHistogram(h) {
  const canvas = $("hist");
  const g = canvas.getContext("2d");
  g.clearRect(0, 0, canvas.width, canvas.height);
  const colours = { R: "#d33", G: "#3a3", B: "#36d", Y: "#888" };
  const w = canvas.width / h.bins;
  let text = `frame ${h.frame}, full scale ${h.full_scale}:`;
  for (const [name, ch] of Object.entries(h.channels)) {
    const top = Math.max(...ch.counts, 1);
    g.strokeStyle = colours[name];
    g.beginPath();
    ch.counts.forEach((c, i) => {
      const y = canvas.height - (Math.log1p(c) / Math.log1p(top)) * canvas.height;
      if (i) g.lineTo(i * w, y);
      else g.moveTo(0, y);
    });
    g.stroke();
    text += ` ${name} clipped ${ch.clipped_high} high / ${ch.clipped_low} low;`;
  }
  $("hist-text").textContent = text;
}

// -- window of interest drawn on the view -------------------------------------------------

const snap = (v, step) => Math.round(v / step) * step;

function woiFromDrag(x0, y0, x1, y1) {
  const img = $("live");
  const p = state.params;
  const win = state.schema.window;
  const sx = p.WOI_WIDTH / img.clientWidth;
  const sy = p.WOI_HEIGHT / img.clientHeight;
  let left = Math.min(x0, x1) * sx;
  let top = Math.min(y0, y1) * sy;
  const width = Math.abs(x1 - x0) * sx;
  const height = Math.abs(y1 - y0) * sy;
  if (p.FLIPH) left = p.WOI_WIDTH - left - width;
  if (p.FLIPV) top = p.WOI_HEIGHT - top - height;
  const step = win.step;
  const w = Math.max(step, Math.min(snap(width, step), win.width));
  const h = Math.max(step, Math.min(snap(height, step), win.height));
  const l = Math.max(0, Math.min(snap(p.WOI_LEFT + left, step), win.width - w));
  const t = Math.max(0, Math.min(snap(p.WOI_TOP + top, step), win.height - h));
  return { WOI_LEFT: l, WOI_TOP: t, WOI_WIDTH: w, WOI_HEIGHT: h };
}

function setupDrag() {
  const view = $("view");
  const box = $("woi-box");
  let start = null;
  const local = (ev) => {
    const r = $("live").getBoundingClientRect();
    return [Math.max(0, Math.min(ev.clientX - r.left, r.width)), Math.max(0, Math.min(ev.clientY - r.top, r.height))];
  };
  view.addEventListener("pointerdown", (ev) => {
    if (!state.schema || !state.schema.window || state.token !== "accepted") return;
    ev.preventDefault();
    view.setPointerCapture(ev.pointerId);
    start = local(ev);
  });
  view.addEventListener("pointermove", (ev) => {
    if (!start) return;
    const [x, y] = local(ev);
    const img = $("live");
    box.hidden = false;
    box.style.left = `${img.offsetLeft + Math.min(start[0], x)}px`;
    box.style.top = `${img.offsetTop + Math.min(start[1], y)}px`;
    box.style.width = `${Math.abs(x - start[0])}px`;
    box.style.height = `${Math.abs(y - start[1])}px`;
    const w = woiFromDrag(start[0], start[1], x, y);
    $("woi-values").textContent = `${w.WOI_WIDTH}×${w.WOI_HEIGHT} at (${w.WOI_LEFT}, ${w.WOI_TOP})`;
  });
  view.addEventListener("pointerup", async (ev) => {
    if (!start) return;
    const [x, y] = local(ev);
    const from = start;
    start = null;
    box.hidden = true;
    if (Math.abs(x - from[0]) < 4 || Math.abs(y - from[1]) < 4) return;
    await setWindow(woiFromDrag(from[0], from[1], x, y));
  });
  $("woi-full").addEventListener("click", () => {
    const win = state.schema && state.schema.window;
    if (win) setWindow({ WOI_LEFT: 0, WOI_TOP: 0, WOI_WIDTH: win.width, WOI_HEIGHT: win.height });
  });
}

async function setWindow(woi) {
  $("woi-values").textContent = `${woi.WOI_WIDTH}×${woi.WOI_HEIGHT} at (${woi.WOI_LEFT}, ${woi.WOI_TOP}): sending`;
  try {
    const answer = await json(`/ports/${state.port}/params`, { method: "PATCH", body: woi });
    state.params = answer.params;
    form.show(answer.params);
    if (!state.quad) liveView(state.port); // the preview's scale follows the window
    $("woi-values").textContent = `${woi.WOI_WIDTH}×${woi.WOI_HEIGHT} at (${woi.WOI_LEFT}, ${woi.WOI_TOP}), frame ${answer.frame}`;
    $("woi-values").dataset.frame = String(answer.frame);
  } catch (e) {
    showError($("woi-values"), e);
  }
}

// -- capture ------------------------------------------------------------------------------

async function capture(count) {
  const status = $("capture-status");
  status.textContent = "capturing…";
  try {
    const answer = await request(`/ports/${state.port}/capture`, { method: "POST", query: { count: String(count) } });
    const blob = await answer.blob();
    const frame = answer.headers.get("x-frame-number");
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `port${state.port}-frame${frame}${count > 1 ? `-x${count}` : ""}.tif`;
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
    status.textContent = `saved ${a.download} (${blob.size} bytes, from frame ${frame})`;
  } catch (e) {
    showError(status, e);
  }
}

$("capture-one").addEventListener("click", () => capture(1));
$("capture-burst").addEventListener("click", () => capture(Number($("burst-count").value) || 1));

// -- events -------------------------------------------------------------------------------

let eventsAbort = null;

async function eventLog() {
  if (eventsAbort) eventsAbort.abort();
  eventsAbort = new AbortController();
  const list = $("events");
  const lastFrameLine = {};
  const add = (text, kind) => {
    const li = document.createElement("li");
    li.className = kind;
    li.textContent = `${new Date().toISOString().slice(11, 19)} ${text}`;
    list.prepend(li);
    while (list.childElementCount > 100) list.lastElementChild.remove();
  };
  try {
    const answer = await request("/events", { signal: eventsAbort.signal });
    for await (const ev of events(answer)) {
      const d = ev.data;
      if (ev.type === "frame") {
        const now = performance.now();
        if (now - (lastFrameLine[d.port] || 0) < 2000) continue; // one line per port per 2 s
        lastFrameLine[d.port] = now;
        add(`port ${d.port} frame ${d.frame}`, "frame");
      } else if (ev.type === "params") {
        if (d.changes && !Object.keys(d.changes).length) continue; // a token check
        add(`port ${d.port} frame ${d.frame}: ${JSON.stringify(d.changes || d.register)}`, "params");
      } else if (ev.type === "error") {
        add(`port ${d.port} error: ${d.detail}`, "error");
      } else add(`${ev.type} ${JSON.stringify(d)}`, ev.type);
    }
  } catch (e) {
    if (e.name !== "AbortError") add(e instanceof NeedsToken ? "events: needs the token" : `events: ${e.message}`, "error");
  }
}

// -- quad overview ------------------------------------------------------------------------

function sensorPorts() {
  return state.info.ports.filter((p) => p.sensor).map((p) => p.port);
}

async function quadLoop() {
  const grid = $("quad-grid");
  const ports = sensorPorts().slice(0, 4);
  grid.replaceChildren(
    ...ports.map((port) => {
      const fig = document.createElement("figure");
      const img = document.createElement("img");
      img.dataset.port = String(port);
      img.alt = `port ${port}`;
      const cap = document.createElement("figcaption");
      cap.dataset.captionFor = String(port);
      cap.textContent = `port ${port}`;
      fig.append(img, cap);
      return fig;
    }),
  );
  const run = {};
  state.quad = run;
  while (state.quad === run) {
    try {
      // The ports' current frames, read until they agree on one trigger (a read can
      // straddle a trigger); then the previews of exactly those frames.
      let frames;
      for (let attempt = 0; attempt < 4; attempt++) {
        frames = await Promise.all(ports.map((port) => json(`/ports/${port}/frame`)));
        if (new Set(frames.map((f) => f.timestamp_ns)).size === 1) break;
      }
      const answers = await Promise.all(
        ports.map((port, k) =>
          request(`/ports/${port}/preview`, { query: { scale: "1/8", frame: String(frames[k].frame) } }),
        ),
      );
      const shots = await Promise.all(answers.map(async (a) => ({ headers: a.headers, blob: await a.blob() })));
      if (state.quad !== run) break;
      const stamps = new Set();
      shots.forEach((shot, k) => {
        const img = grid.querySelector(`img[data-port="${ports[k]}"]`);
        const old = img.src;
        img.src = URL.createObjectURL(shot.blob);
        if (old.startsWith("blob:")) URL.revokeObjectURL(old);
        const frame = shot.headers.get("x-frame-number");
        const ns = shot.headers.get("x-timestamp-ns");
        img.dataset.frame = frame;
        img.dataset.timestampNs = ns;
        stamps.add(ns);
        grid.querySelector(`[data-caption-for="${ports[k]}"]`).textContent = `port ${ports[k]} · frame ${frame} · ${timeOf(ns)}`;
      });
      $("quad-sync").textContent = stamps.size === 1
        ? `all ${ports.length} ports show the same trigger (${timeOf([...stamps][0])})`
        : `ports differ: ${stamps.size} different timestamps`;
      $("quad-sync").dataset.sync = String(stamps.size === 1);
    } catch (e) {
      showError($("quad-sync"), e);
      if (e instanceof NeedsToken) return;
      await new Promise((r) => setTimeout(r, 2000));
    }
    await new Promise((r) => setTimeout(r, 200));
  }
}

$("quad").addEventListener("change", () => {
  const on = $("quad").checked;
  $("single").hidden = on;
  $("quad-view").hidden = !on;
  if (on) {
    stopStream();
    quadLoop();
  } else {
    state.quad = null;
    liveView(state.port);
  }
});

// -- ports --------------------------------------------------------------------------------

async function selectPort(port) {
  state.port = port;
  for (const b of document.querySelectorAll("#ports button")) b.setAttribute("aria-pressed", String(Number(b.dataset.port) === port));
  try {
    state.schema = await loadSchema(port);
    form.build(state.schema);
    $("controls-sensor").textContent = `port ${port}: ${state.schema.sensor}`;
    state.params = await json(`/ports/${port}/params`);
    form.show(state.params);
  } catch (e) {
    showError($("view-error"), e);
  }
  if (!state.quad) liveView(port);
}

async function restart() {
  try {
    state.info = await json("/info");
  } catch (e) {
    showError($("view-error"), e);
    return;
  }
  $("board").textContent = `· ${state.info.board} · ${state.info.version}`;
  const nav = $("ports");
  nav.replaceChildren(
    ...sensorPorts().map((port) => {
      const b = document.createElement("button");
      b.type = "button";
      b.dataset.port = String(port);
      const entry = state.info.ports.find((p) => p.port === port);
      b.textContent = `port ${port} ${entry.sensor.model}`;
      b.addEventListener("click", () => selectPort(port));
      return b;
    }),
  );
  document.querySelector(".quad-toggle").hidden = sensorPorts().length < 2;
  const ports = sensorPorts();
  await selectPort(ports.includes(state.port) ? state.port : ports[0]);
  eventLog();
}

showToken(token() ? "checking" : "none");
setupDrag();
histogramLoop();
tokenChanged();
