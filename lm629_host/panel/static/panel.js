// lm629 panel: the page.  Rows arrive by Server-Sent Events (events), commands go by POST
// with the token (api/command).  URLs are relative, so the page works behind an SSH forward.
"use strict";
const config = JSON.parse(document.getElementById("config").textContent);
const WINDOW_S = 8;
const BAD = new Set(["COMMAND_ERROR", "POSITION_ERROR", "WRAPAROUND", "MOTOR_OFF"]);
const $ = (id) => document.getElementById(id);
const state = {client: null, commands: false, rows: 0, redraws: 0, axes: {}};
window.panelState = state;  // read by the browser tests

function makeAxis(name, k) {
  const box = document.createElement("div");
  box.className = "axis";
  box.id = "axis-" + k;
  box.innerHTML = `<h2>axis ${name}</h2><div class="readout"></div>
    <div class="lights status"></div><div class="lights signals"></div>`;
  $("plots").appendChild(box);
  const lights = (cls, bits) => bits.map(([n, v]) => {
    const el = document.createElement("span");
    el.className = "light"; el.textContent = n.toLowerCase().replaceAll("_", " ");
    el.dataset.bit = v; el.dataset.name = n;
    box.querySelector(cls).appendChild(el);
    return el;
  });
  const ax = {name, t: [], dp: [], ap: [], dv: [], av: [], fe: [],
              status: lights(".status", config.status_bits),
              signals: lights(".signals", config.signal_bits),
              readout: box.querySelector(".readout")};
  const width = () => Math.max(300, $("plots").clientWidth - 12);
  const plot = (title, unit, series) => new uPlot({
    title, width: width(), height: config.axes.length > 1 ? 110 : 150, legend: {show: true},
    scales: {x: {time: false}},
    axes: [{label: "s"}, {label: unit, size: 70}],
    // a null (the actual velocity of a row with no previous one to measure from) is spanned
    series: [{label: "t"}, ...series.map(([label, stroke, dash]) => ({label, stroke, width: 1.5, dash,
                                                                      spanGaps: true}))],
  }, [[], ...series.map(() => [])], box);
  ax.plots = [
    plot("position", "counts", [["desired", "#1e88e5", [6, 3]], ["actual", "#e53935"]]),
    plot("velocity", "counts/s", [["desired", "#1e88e5", [6, 3]], ["actual", "#e53935"]]),
    plot("following error", "counts", [["error", "#8e24aa"]]),
  ];
  state.axes[name] = ax;
  return ax;
}

const axes = config.axes.map(makeAxis);
for (const name of config.axes) {
  const o = document.createElement("option"); o.textContent = name; $("axis").appendChild(o);
}
$("source").textContent = "samples: " + config.source;
$("where").textContent = config.title;
showFailsafe(config.failsafe);
if (config.fault) showFault(config.fault);

function showFault(text) { $("fault").hidden = false; $("fault").textContent = text; }

function showFailsafe(f) {
  const el = $("failsafe");
  el.textContent = f.text;
  el.className = f.tripped ? "tripped" : "";
  $("clear").hidden = !f.tripped;
  if (!f.tripped && $("fault").textContent.startsWith("failsafe trip")) $("fault").hidden = true;
}

function light(el, on) { el.classList.toggle("on", on); el.classList.toggle("bad", BAD.has(el.dataset.name)); }

function addRows(rows) {
  for (const row of rows) {
    axes.forEach((ax, k) => {
      const o = 1 + 6 * k;
      ax.t.push(row[0]); ax.dp.push(row[o]); ax.ap.push(row[o + 1]);
      ax.dv.push(row[o + 2]); ax.av.push(row[o + 3]); ax.fe.push(row[o] - row[o + 1]);
      ax.last = row.slice(o, o + 6);
      if (row[o + 3] !== null) ax.velocity = row[o + 3];
    });
  }
  state.rows += rows.length;
}

function redraw() {
  for (const ax of axes) {
    if (!ax.t.length) continue;
    const end = ax.t[ax.t.length - 1];
    let cut = 0;
    while (cut < ax.t.length && ax.t[cut] < end - WINDOW_S) cut++;
    if (cut) for (const key of ["t", "dp", "ap", "dv", "av", "fe"]) ax[key].splice(0, cut);
    ax.plots[0].setData([ax.t, ax.dp, ax.ap]);
    ax.plots[1].setData([ax.t, ax.dv, ax.av]);
    ax.plots[2].setData([ax.t, ax.fe]);
    const [dp, ap, , , st, sig] = ax.last;
    ax.readout.textContent = `desired ${dp}  actual ${ap}  error ${dp - ap}  velocity ${ax.velocity ?? "--"} counts/s`;
    ax.status.forEach((el) => light(el, (st & el.dataset.bit) !== 0));
    ax.signals.forEach((el) => light(el, (sig & el.dataset.bit) !== 0));
  }
  state.redraws++;
}

function log(line) {
  const el = $("log");
  el.textContent = (line + "\n" + el.textContent).slice(0, 20000);
}

function showOutcome(r) {
  const msg = $("msg");
  msg.textContent = r.ok ? r.text : "lm629: " + r.text;
  msg.className = "msg " + (r.ok ? "ok" : "error");
}

const events = new EventSource("events?token=" + encodeURIComponent(config.token));
events.onmessage = (e) => {
  const m = JSON.parse(e.data);
  if (m.type === "rows") { addRows(m.rows); redraw(); }
  else if (m.type === "hello") { state.client = m.client; showFailsafe(m.failsafe); if (m.fault) showFault(m.fault); }
  else if (m.type === "role") {
    state.commands = m.commands;
    $("role").textContent = m.commands ? "this tab commands" : "this tab watches: " + m.why;
    $("role").className = "role" + (m.commands ? "" : " watch");
  }
  else if (m.type === "failsafe") { showFailsafe(m); if (m.tripped) showFault("failsafe trip: " + m.text); }
  else if (m.type === "fault") showFault(m.text);
  else if (m.type === "log") log(`${m.ok ? "" : "lm629: "}${m.text}  [${m.axis}: lm629 ${m.argv.join(" ")}]`);
};
events.onerror = () => { $("role").textContent = "disconnected (the panel ended?)"; };

async function command(body) {
  body.client = state.client;
  body.axis = $("axis").value;
  let r;
  try {
    const resp = await fetch("api/command", {
      method: "POST", headers: {"Content-Type": "application/json", "X-LM629-Token": config.token},
      body: JSON.stringify(body)});
    r = await resp.json();
  } catch (err) {
    r = {ok: false, text: "no answer from the panel: " + err};
  }
  showOutcome(r);
  return r;
}

const val = (id) => $(id).value;
function stop() { return command({cmd: "stop", mode: val("stop-mode")}); }
$("stop").onclick = stop;
document.addEventListener("keydown", (e) => { if (e.key === "Escape") { e.preventDefault(); stop(); } });
$("move").onclick = () => command({cmd: "move", target: val("move-target"), shape: val("move-shape"),
  vel: val("move-vel"), acc: val("move-acc"), jerk: val("move-jerk"), relative: $("move-relative").checked});
const gains = () => ({kp: val("gain-kp"), ki: val("gain-ki"), kd: val("gain-kd"), il: val("gain-il"), ds: val("gain-ds")});
$("clear").onclick = () => command({cmd: "clear"});
$("apply").onclick = () => command({cmd: "filter", ...gains()});

let stepPlot = null;
$("step").onclick = async () => {
  const r = await command({cmd: "step", distance: val("step-distance"), time: val("step-time"),
    vel: val("step-vel"), acc: val("step-acc"), ...gains()});
  if (!r.ok || !r.data) return;
  const d = r.data;
  const data = [d.t, d.desired, d.actual, d.predicted || d.t.map(() => null)];
  $("step-note").textContent = "prediction: " + d.basis;
  if (stepPlot) { stepPlot.setData(data); return; }
  stepPlot = new uPlot({title: "step: measured and predicted", width: 360, height: 200,
    scales: {x: {time: false}}, axes: [{label: "s"}, {size: 60}],
    series: [{label: "t"}, {label: "desired", stroke: "#1e88e5", dash: [6, 3]},
             {label: "measured", stroke: "#e53935", width: 1.5},
             {label: "predicted", stroke: "#43a047", width: 1.5, dash: [2, 2]}]}, data, $("step-plot"));
  state.stepPlot = stepPlot;
};
