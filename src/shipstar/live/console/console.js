// shipstar live: operator console.  Read-only: it only listens to /events (server-sent
// events) and loads /thumb/SENSOR.png; it sends nothing.  No library, no network
// fetch beyond this server.
"use strict";
(function () {
  const SPAN_S = 600;                       // the plots: the last 10 minutes
  const COLORS = ["#5ab0ff", "#ff8c5a", "#7be07b", "#e8c547", "#d17bff", "#5ae0d1"];
  const state = { run: null, hist: [], snap: null, messages: 0, connected: false, lastPlot: 0, thumbs: {} };
  window.shipstarConsole = state;           // for tests and the curious

  const $ = (id) => document.getElementById(id);
  const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
  const shown = {};                         // element id -> HTML last written (write only changes)
  function put(id, html) {
    if (shown[id] === html) return;
    shown[id] = html;
    $(id).innerHTML = html;
  }
  const fix = (v, d) => (v === null || v === undefined || !isFinite(v)) ? "-" : Number(v).toFixed(d);

  function duration(s) {
    if (s === null || s === undefined || !isFinite(s)) return "-";
    const a = Math.abs(s), sign = s < 0 ? "-" : "";
    if (a < 60) return sign + a.toFixed(a < 10 ? 2 : 1) + " s";
    if (a < 3600) return sign + (a / 60).toFixed(1) + " min";
    if (a < 86400) return sign + (a / 3600).toFixed(1) + " h";
    if (a < 86400 * 400) return sign + (a / 86400).toFixed(1) + " d";
    return sign + (a / 86400 / 365.25).toFixed(1) + " y";
  }

  function setConn(on) {
    state.connected = on;
    const b = $("conn");
    b.textContent = on ? "live" : "reconnecting";
    b.className = "badge " + (on ? "on" : "off");
  }

  // -- the event stream ------------------------------------------------------------------------
  let es = null;
  function connect() {
    es = new EventSource("/events");
    es.addEventListener("hello", (ev) => {
      const run = JSON.parse(ev.data).run;
      if (run !== state.run) { state.run = run; state.hist = []; state.thumbs = {}; state.plotted = null; }
      setConn(true);
    });
    es.onmessage = (ev) => {
      const m = JSON.parse(ev.data);
      for (const p of m.h) state.hist.push(p);
      if (state.hist.length) {
        const tmax = state.hist[state.hist.length - 1].t;
        let k = 0;
        while (k < state.hist.length && state.hist[k].t < tmax - SPAN_S) k++;
        if (k) state.hist.splice(0, k);
      }
      if (m.s) { state.snap = m.s; state.messages++; render(m.s); }
      setConn(true);
    };
    es.onerror = () => {
      setConn(false);
      if (es.readyState === EventSource.CLOSED) { es = null; setTimeout(connect, 1000); }
    };
  }

  // -- rendering ---------------------------------------------------------------------------------
  function cell(v, d, cls) {
    const ok = v !== null && v !== undefined && isFinite(v);
    return `<td class="num ${cls || ""}"${ok ? ` data-value="${v}"` : ""}>${fix(v, d)}</td>`;
  }

  function nowRow(key, label, r, inUse, integrity) {
    if (!r) return "";
    const id = "now-" + key;
    const sig = r.solved ? `${fix(r.sigma_heading_arcsec, 2)} / ${fix(r.sigma_pitch_arcsec, 2)} / ${fix(r.sigma_roll_arcsec, 2)}` : "-";
    const h = r.solved ? r.heading_deg : null, p = r.solved ? r.pitch_deg : null, ro = r.solved ? r.roll_deg : null;
    let integ = "";
    if (integrity) integ = `<span class="${integrity.label === "ok" ? "ok" : "bad"}">${esc(integrity.label)}</span>`;
    const why = r.solved ? "" : `<span class="warn" title="${esc(r.reason || "")}"> unsolved: ${esc((r.reason || "").slice(0, 60))}</span>`;
    return `<tr id="${id}" class="${inUse ? "inuse" : ""}" data-time="${esc(r.time_utc)}">` +
      `<td>${esc(label)}${why}</td>` +
      cell(h, 6, "h") + cell(p, 6, "p") + cell(ro, 6, "r") +
      `<td class="num sig">${sig}</td><td class="num">${r.n_stars === null ? "-" : r.n_stars}</td><td>${integ}</td></tr>`;
  }

  function render(s) {
    $("server-utc").textContent = s.server_utc.replace("T", " ");
    $("run-s").textContent = duration(s.run_s);
    $("epochs").textContent = s.epochs + (s.inconsistent ? ` (${s.inconsistent} inconsistent)` : "");
    const lat = s.latency || {};
    $("latency").textContent = lat.median_ms === null || lat.median_ms === undefined ? "-" :
      `${fix(lat.median_ms, 0)} / ${fix(lat.p99_ms, 0)} ms`;
    $("eop").textContent = s.eop || "-";
    $("eop").className = s.eop === "extrapolated" ? "bad" : "";
    $("now-method").textContent = s.method;
    const n = s.now;
    if (n) {
      $("now-time").textContent = n.time_utc || "-";
      $("now-age").textContent = duration(n.age_s);
      $("now-behind").textContent = duration(n.epoch_age_s);
      let rows = "";
      const methods = n.methods || {};
      for (const m of ["joint", "seed-rule", "single"]) {
        if (methods[m]) rows += nowRow(m, m, methods[m], s.method === m || (m === "single" && !methods.joint), m === "joint" ? n.integrity : null);
      }
      for (const name of s.sensors_order) {
        const r = (n.singles || {})[name];
        if (r) rows += nowRow("sensor-" + name, name + " alone", r, s.method === "single" && name === s.reference, null);
      }
      put("now-body", rows);
    }
    renderAlarms(s.alarms || []);
    renderSensors(s);
    const t = performance.now(), newest = state.hist.length ? state.hist[state.hist.length - 1].t : null;
    if (t - state.lastPlot > 950 && newest !== state.plotted) {       // plots: at most once a second
      state.lastPlot = t; state.plotted = newest; plots(s);
    }
  }

  function renderAlarms(alarms) {
    const active = alarms.filter((a) => !a.until_utc).length;
    $("alarm-count").textContent = active ? `${active} active` : "none active";
    $("alarm-count").className = "sub" + (active ? " bad" : "");
    put("alarms", alarms.length ? alarms.map((a) =>
      `<li class="${a.until_utc ? "past" : "active"}" data-kind="${esc(a.kind)}"><span class="t">${esc(a.since_utc.slice(11, 19))}` +
      `${a.until_utc ? "-" + esc(a.until_utc.slice(11, 19)) : ""}</span>${esc(a.kind)}: ${esc(a.text)}</li>`).join("")
      : '<li class="muted">none</li>');
  }

  function ensureSensor(name) {
    let el = $("sensor-" + name);
    if (el) return el;
    el = document.createElement("section");
    el.className = "card";
    el.id = "sensor-" + name;
    el.innerHTML = `<h2>Sensor ${esc(name)} <span class="sub" id="sensor-${esc(name)}-state"></span></h2>` +
      `<div class="sensor"><img id="thumb-${esc(name)}" alt="newest solved frame of ${esc(name)}">` +
      `<table><tbody id="sensor-${esc(name)}-body"></tbody></table></div>`;
    $("sensors").appendChild(el);
    return el;
  }

  function renderSensors(s) {
    for (const name of s.sensors_order) {
      ensureSensor(name);
      const v = s.sensors[name];
      const share = v.solved_share === null ? "-" : `${(100 * v.solved_share).toFixed(0)} % (${v.solved_minute} of ${v.n_minute})`;
      const reasons = Object.entries(v.reasons || {}).map(([k, c]) => `${esc(k)}: ${c}`).join("; ") || "none";
      const rows = [["frames in", `<span data-value="${v.frames_in}" id="frames-in-${esc(name)}">${v.frames_in}</span>`],
        ["solved, last minute", share], ["stars used", v.stars === null || v.stars === undefined ? "-" : v.stars],
        ["residual RMS", v.rms_arcsec === null ? "-" : fix(v.rms_arcsec, 2) + "''"],
        ["lag", duration(v.lag_s)], ["waiting / skipped behind", `${v.waiting} / ${v.skipped_behind}`],
        ["newest frame", esc(v.last_frame || "-")],
        ["unsolved reasons", `<span class="reasons">${reasons}</span>`]];
      put(`sensor-${name}-body`, rows.map(([k, x]) => `<tr><td>${k}</td><td>${x}</td></tr>`).join(""));
      const st = $(`sensor-${name}-state`);
      st.textContent = v.absent ? "frames stopped" : "receiving";
      st.className = "sub " + (v.absent ? "bad" : "ok");
      const th = state.thumbs[name] || { seq: 0, at: 0 };
      const now = performance.now();
      if (v.thumb > 0 && v.thumb !== th.seq && now - th.at >= 1000) {      // at most once a second
        state.thumbs[name] = { seq: v.thumb, at: now };
        $("thumb-" + name).src = `/thumb/${encodeURIComponent(name)}.png?run=${state.run}&v=${v.thumb}`;
      }
    }
  }

  // -- plots: plain canvas ----------------------------------------------------------------------
  function plots(s) {
    const H = state.hist;
    const tmax = H.length ? H[H.length - 1].t : 0;
    const have = H.length ? tmax - H[0].t : 0;           // up to 10 minutes, at least 30 s
    span = [30, 60, 120, 300, 600].find((x) => x >= have) || SPAN_S;
    const line = (name, color, get) => ({ name, color, pts: H.map((p) => [p.t, get(p)]) });
    const names = s.sensors_order;
    plot($("plot-h"), [line("heading", COLORS[0], (p) => p.h)], tmax);
    plot($("plot-p"), [line("pitch", COLORS[1], (p) => p.p)], tmax);
    plot($("plot-r"), [line("roll", COLORS[2], (p) => p.r)], tmax);
    plot($("plot-rms"), names.map((n, i) => line(n, COLORS[i % COLORS.length], (p) => (p.rms || {})[n])), tmax);
    plot($("plot-dis"), [line("largest sensor - mean", COLORS[3], (p) => p.dis)], tmax);
    const others = names.filter((n) => n !== s.reference);
    plot($("plot-clk"), others.map((n, i) => line(`${n} - ${s.reference}`, COLORS[(i + 1) % COLORS.length], (p) => (p.clk || {})[n])), tmax);
    const flx = [];
    others.forEach((n, i) => ["bow", "up", "stbd"].forEach((ax, k) =>
      flx.push(line(`${n} ${ax}`, COLORS[(3 * i + k) % COLORS.length], (p) => ((p.flx || {})[n] || [])[k]))));
    plot($("plot-flx"), flx, tmax);
    plot($("plot-ins"), ["heading", "pitch", "roll"].map((ax, k) => line(ax, COLORS[k], (p) => (p.ins || [])[k])), tmax);
  }
  let span = 60;

  function niceTicks(lo, hi, n) {
    const span = hi - lo, raw = span / n, mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map((m) => m * mag).find((x) => span / x <= n) || 10 * mag;
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-12 * Math.abs(hi); v += step) out.push(v);
    return { ticks: out, step };
  }

  function plot(cv, series, tmax) {
    const dpr = window.devicePixelRatio || 1, W = cv.clientWidth, Hh = cv.clientHeight;
    if (cv.width !== Math.round(W * dpr)) { cv.width = Math.round(W * dpr); cv.height = Math.round(Hh * dpr); }
    const g = cv.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, W, Hh);
    g.font = "11px system-ui, sans-serif";
    g.fillStyle = "#d8e2ea";
    g.fillText(cv.dataset.title, 8, 13);
    const L = 70, R = 8, T = 22, B = 18, pw = W - L - R, ph = Hh - T - B;
    let lo = Infinity, hi = -Infinity;
    for (const s of series) for (const [t, v] of s.pts) if (v !== null && v !== undefined && isFinite(v) && t >= tmax - span) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (!isFinite(lo)) {
      g.fillStyle = "#7f93a5";
      g.fillText("no data (yet)", L + pw / 2 - 30, T + ph / 2);
      return;
    }
    if (hi - lo < 1e-9) { const c = (hi + lo) / 2, d = Math.max(Math.abs(c) * 1e-6, 1e-6); lo = c - d; hi = c + d; }
    const pad = 0.08 * (hi - lo); lo -= pad; hi += pad;
    const x = (t) => L + pw * (t - (tmax - span)) / span, y = (v) => T + ph * (hi - v) / (hi - lo);
    g.strokeStyle = "#2a3a4a"; g.lineWidth = 1; g.fillStyle = "#7f93a5";
    const { ticks, step } = niceTicks(lo, hi, 4);
    const dec = Math.max(0, Math.min(8, -Math.floor(Math.log10(step))));
    for (const v of ticks) {
      g.beginPath(); g.moveTo(L, y(v)); g.lineTo(L + pw, y(v)); g.stroke();
      g.fillText(v.toFixed(dec), 4, y(v) + 4);
    }
    const every = span / 5;
    for (let k = 0; k <= 5; k++) {
      const xx = x(tmax - k * every), m = k * every;
      g.beginPath(); g.moveTo(xx, T); g.lineTo(xx, T + ph); g.stroke();
      g.fillText(k ? (m >= 60 ? `-${m / 60} min` : `-${m} s`) : "now", Math.min(xx - 14, W - 30), Hh - 4);
    }
    let lx = L + pw;
    series.forEach((s) => {
      g.strokeStyle = s.color; g.lineWidth = 1.5; g.beginPath();
      let prev = null, drawn = false;
      for (const [t, v] of s.pts) {
        if (v === null || v === undefined || !isFinite(v) || t < tmax - span) { prev = null; continue; }
        if (prev === null || t - prev > 5) g.moveTo(x(t), y(v)); else g.lineTo(x(t), y(v));
        prev = t; drawn = true;
      }
      g.stroke();
      if (drawn) {
        const w = g.measureText(s.name).width + 16;
        lx -= w;
        g.fillStyle = s.color; g.fillRect(lx, 6, 10, 3);
        g.fillStyle = "#d8e2ea"; g.fillText(s.name, lx + 13, 13);
      }
    });
  }

  connect();
})();
