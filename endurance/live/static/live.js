// The live page: the stream (/live, server-sent events) into uPlot charts, the status into the
// counters, the events into their list; the operator's actions POSTed with the token typed here
// (kept in this page only). window.live holds what the page got, for the browser tests.
"use strict";
(function () {
  const COLORS = ["#58a6ff", "#3fb950", "#f778ba", "#a371f7", "#39c5cf", "#ff7b72", "#e3b341", "#79c0ff"];
  const DIM = "#8d9aa8", GRID = "#2c3540", VALVE = "#d29922", ERROR = "#ff7b72";
  const MAX_EVENTS = 200, TREND_FLIGHTS = 500;
  const live = window.live = {counts: {}, sampleArrivals: [], charts: {}, status: null, page: null,
                              events: [], trend: [], lastAction: null};
  let channels = [], windowS = 30;
  let T = [], Y = [], R = [], U = [];
  let dirty = false, trendDirty = false;
  const $ = (id) => document.getElementById(id);

  // -- figures formatted as stand test status prints them ------------------------------------------
  const whole = (v) => v == null ? "–" : Number(v).toLocaleString("en-US");
  function duration(s) {            // endurance.report._duration
    if (s < 120) return s.toFixed(0) + " s";
    if (s < 7200) return (s / 60).toFixed(1) + " min";
    if (s < 3 * 86400) return (s / 3600).toFixed(1) + " h";
    return (s / 86400).toFixed(1) + " days";
  }
  const FORMAT = {
    flights_done: whole, flights_target: whole, "flight.number": whole, load_case: whole,
    "flight.load_cases": whole, "flight.type": (v) => v == null ? "–" : String(v),
    pace_flights_per_h: (v) => v == null ? "–" : v.toFixed(0),
    eta_s: (v) => v == null ? "–" : duration(v),
    state: (v) => v == null ? "–" : String(v), reason: (v) => v == null ? "" : String(v),
  };
  const field = (obj, path) => path.split(".").reduce((o, k) => (o == null ? null : o[k]), obj);

  function showStatus(s) {
    live.status = s;
    document.querySelectorAll("[data-status]").forEach((el) => {
      const key = el.dataset.status, v = field(s, key);
      el.dataset.value = JSON.stringify(v === undefined ? null : v);
      el.textContent = (FORMAT[key] || String)(v);
    });
    $("name").textContent = s.name;
    document.title = `${s.name}: ${s.state}, ${s.flights_done} of ${s.flights_target}`;
    $("state").className = "badge " + s.state;
    $("eta-clock").textContent = s.eta_s ? "at " + new Date(Date.now() + s.eta_s * 1000).toLocaleString() : "";
  }

  // -- the channels: force against reference and the valve command, the error ----------------------
  function xRange(u, min, max) { return max == null ? [0, 1] : [max - windowS, max]; }
  const axis = (extra) => Object.assign({stroke: DIM, grid: {stroke: GRID, width: 1}, ticks: {stroke: GRID}}, extra);

  function makeChannels(names) {
    channels = names;
    T = []; Y = names.map(() => []); R = names.map(() => []); U = names.map(() => []);
    const box = $("channels");
    box.replaceChildren();
    live.charts = {};
    names.forEach((name, i) => {
      const panel = document.createElement("div");
      panel.className = "channel";
      panel.dataset.channel = name;
      panel.innerHTML = `<h3></h3><div class="readout"><span class="force">force</span> <b class="y">–</b> kgf
        · <span class="reference">reference</span> <b class="r">–</b> · <span class="error-label">error</span>
        <b class="err">–</b> · <span class="valve">valve</span> <b class="u">–</b> %</div>
        <div class="main"></div><div class="error"></div>`;
      panel.querySelector("h3").textContent = name;
      panel.querySelector("h3").style.color = COLORS[i % COLORS.length];
      panel.querySelector(".force").style.color = COLORS[i % COLORS.length];
      box.appendChild(panel);
      const width = Math.max(panel.clientWidth - 16, 200);
      const main = new uPlot({
        width, height: 170, legend: {show: false}, cursor: {show: false},
        scales: {x: {time: true, range: xRange}, kgf: {}, pct: {}},
        series: [{}, {label: "force", scale: "kgf", stroke: COLORS[i % COLORS.length], width: 1.5},
                 {label: "reference", scale: "kgf", stroke: DIM, width: 1, dash: [5, 4]},
                 {label: "valve", scale: "pct", stroke: VALVE, width: 1}],
        axes: [axis({}), axis({scale: "kgf", size: 60}), axis({scale: "pct", side: 1, size: 45, grid: {show: false}})],
      }, [[], [], [], []], panel.querySelector(".main"));
      const error = new uPlot({
        width, height: 80, legend: {show: false}, cursor: {show: false},
        scales: {x: {time: true, range: xRange}},
        series: [{}, {label: "error", stroke: ERROR, width: 1}],
        axes: [axis({show: false}), axis({size: 60, label: "error kgf", labelSize: 14}), axis({side: 1, size: 45, show: false})],
      }, [[], []], panel.querySelector(".error"));
      live.charts[name] = {main, error, panel};
    });
  }

  function addSamples(d) {
    live.counts.samples = (live.counts.samples || 0) + 1;
    live.sampleArrivals.push(Date.now() / 1000);
    if (live.sampleArrivals.length > 400) live.sampleArrivals.splice(0, 200);
    if (!channels.length || d.y.length !== channels.length) return;
    // after a reconnection the greeting's window repeats what the page has: only the newer rows
    let first = 0;
    const last = T.length ? T[T.length - 1] : -Infinity;
    while (first < d.t.length && d.t[first] <= last) first++;
    if (first === d.t.length) return;
    for (const t of d.t.slice(first)) T.push(t);
    channels.forEach((_, i) => {
      for (const v of d.y[i].slice(first)) Y[i].push(v);
      for (const v of d.r[i].slice(first)) R[i].push(v);
      for (const v of d.u[i].slice(first)) U[i].push(v);
    });
    const newest = T[T.length - 1];
    let cut = 0;
    while (cut < T.length && T[cut] < newest - windowS - 1) cut++;
    if (cut) {
      T.splice(0, cut);
      channels.forEach((_, i) => { Y[i].splice(0, cut); R[i].splice(0, cut); U[i].splice(0, cut); });
    }
    dirty = true;
  }

  const show = (v, digits) => v == null ? "–" : v.toFixed(digits);
  function redraw() {
    if (dirty && T.length) {
      dirty = false;
      live.counts.redraws = (live.counts.redraws || 0) + 1;
      const last = T.length - 1;
      channels.forEach((name, i) => {
        const c = live.charts[name];
        const E = T.map((_, k) => (R[i][k] == null || Y[i][k] == null) ? null : R[i][k] - Y[i][k]);
        c.main.setData([T, Y[i], R[i], U[i]]);
        c.error.setData([T, E]);
        const p = c.panel;
        p.querySelector(".y").textContent = show(Y[i][last], 0);
        p.querySelector(".r").textContent = show(R[i][last], 0);
        p.querySelector(".err").textContent = show(E[last], 1);
        p.querySelector(".u").textContent = show(U[i][last], 2);
      });
    }
    if (trendDirty) { trendDirty = false; drawTrends(); }
    requestAnimationFrame(redraw);
  }

  // -- the events --------------------------------------------------------------------------------------
  const seen = new Set();
  function clock(t) {
    const d = new Date(t * 1000);
    return d.toLocaleTimeString("en-GB", {hour12: false}) + "." + String(d.getMilliseconds()).padStart(3, "0");
  }
  function addEvents(list) {
    const ol = $("events");
    for (const e of list) {
      if (seen.has(e.id)) continue;
      seen.add(e.id);
      live.events.push(Object.assign({shown: Date.now() / 1000}, e));
      const li = document.createElement("li");
      li.className = "kind-" + e.kind;
      li.dataset.id = e.id;
      li.dataset.kind = e.kind;
      li.dataset.time = e.time;
      li.dataset.shown = Date.now() / 1000;
      li.innerHTML = `<time></time><span class="kind"></span><span class="channel-name"></span><span class="message"></span>`;
      li.querySelector("time").textContent = clock(e.time);
      li.querySelector(".kind").textContent = e.kind;
      li.querySelector(".channel-name").textContent = e.channel || "";
      li.querySelector(".message").textContent = e.message + (e.flight ? ` (flight ${e.flight})` : "");
      ol.prepend(li);
    }
    while (ol.children.length > MAX_EVENTS) ol.lastChild.remove();
  }

  // -- the end points' trends ----------------------------------------------------------------------------
  let trendCharts = null;
  function drawTrends() {
    const rows = live.trend;
    if (!channels.length) return;
    const x = rows.map((r) => r.flight);
    const pick = (key) => channels.map((name) => rows.map((r) => (r.channels[name] || {})[key] ?? null));
    const data = {error: [x, ...pick("error_pct")], flow: [x, ...pick("flow_rise_pct")]};
    if (!trendCharts) {
      trendCharts = {};
      for (const [key, id] of [["error", "trend-error"], ["flow", "trend-flow"]]) {
        const el = $(id);
        trendCharts[key] = new uPlot({
          width: Math.max(el.clientWidth, 300), height: 200, legend: {show: true},
          scales: {x: {time: false}},
          series: [{label: "flight"}, ...channels.map((name, i) => ({label: name, stroke: COLORS[i % COLORS.length],
                                                                   width: 1, points: {show: true, size: 4}}))],
          axes: [axis({label: "flight", labelSize: 14, incrs: [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000]}),
                 axis({size: 50})],
        }, data[key], el);
      }
      live.charts.trend = trendCharts;
    } else {
      trendCharts.error.setData(data.error);
      trendCharts.flow.setData(data.flow);
    }
  }
  function addTrend(rows) {
    const byFlight = new Map(live.trend.map((r) => [r.flight, r]));
    for (const r of rows) byFlight.set(r.flight, r);
    live.trend = [...byFlight.values()].sort((a, b) => a.flight - b.flight).slice(-TREND_FLIGHTS);
    trendDirty = true;
  }

  // -- the page and the session ------------------------------------------------------------------------
  function showPage(p) {
    live.page = p;
    windowS = p.window_s;
    if (p.channels.join() !== channels.join()) makeChannels(p.channels);
    const note = $("operator-note");
    const buttons = document.querySelectorAll("#operator button");
    if (p.read_only) {
      note.textContent = "read-only: this server was started without --operator-token-file";
      buttons.forEach((b) => { b.disabled = true; });
      $("token").disabled = true;
    } else {
      note.textContent = "actions need the operator's token";
    }
    $("resume").hidden = !p.actions.includes("resume");
    showSession(p.session);
  }
  function showSession(s) {
    const badge = $("session");
    badge.className = "badge " + (s ? "live" : "down");
    badge.textContent = s ? `live: session ${s.pid}, ${Math.round(s.sample_hz)} samples/s` : "no session running";
  }

  // -- the operator's actions ------------------------------------------------------------------------------
  async function act(action) {
    if (action === "stop" && !window.confirm("Stop now: every channel unloads keeping the load ratios, then holds.")) return;
    const token = $("token").value.trim();
    const headers = token ? {"Authorization": "Bearer " + token} : {};
    const out = $("action-result");
    let status = 0, body = {};
    try {
      const res = await fetch("/" + action, {method: "POST", headers});
      status = res.status;
      body = await res.json().catch(() => ({}));
    } catch (err) {
      body = {refused: String(err)};
    }
    const ok = status === 200;
    out.className = ok ? "done" : "refused";
    out.dataset.status = status;
    out.textContent = ok ? body.message : `${action} refused (${status}): ${body.refused || body.error || "no answer"}`;
    live.lastAction = {action, status, body, at: Date.now() / 1000};
  }
  document.querySelectorAll("#operator button").forEach((b) => b.addEventListener("click", () => act(b.dataset.action)));

  // -- the stream ----------------------------------------------------------------------------------------
  // EventSource opens the stream again by itself after a dropped connection (the server says
  // after how long); after a refusal (a server at its limit of streams, 503) it gives up, so the
  // page opens a new one itself a little later.
  let stream = null;
  function openStream() {
    stream = new EventSource("/live");
    const on = (name, fn) => stream.addEventListener(name, (e) => {
      live.counts[name + "_messages"] = (live.counts[name + "_messages"] || 0) + 1;
      fn(JSON.parse(e.data));
    });
    on("page", showPage);
    on("session", (m) => { if (m.channels.join() !== channels.join()) makeChannels(m.channels); showSession(m.session); });
    on("samples", addSamples);
    on("status", showStatus);
    on("events", addEvents);
    on("trend", addTrend);
    stream.onerror = () => {
      const b = $("session");
      b.className = "badge down";
      b.textContent = "server unreachable: retrying";
      if (stream.readyState === EventSource.CLOSED) setTimeout(openStream, 5000);
    };
  }
  openStream();
  window.addEventListener("resize", () => {
    for (const c of Object.values(live.charts)) {
      if (c.panel) { const w = Math.max(c.panel.clientWidth - 16, 200); c.main.setSize({width: w, height: 170}); c.error.setSize({width: w, height: 80}); }
    }
  });
  requestAnimationFrame(redraw);
})();
