#include "web/internal/page.h"

namespace bp::internal {

namespace {

// The whole page: layout, styles and the script that polls the status JSON
// and the overlay images.
constexpr std::string_view kStatusPage = R"HTML(<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>binpick status</title>
<style>
body { font-family: sans-serif; margin: 1em; background: #fafafa; color: #222; }
h1 { font-size: 1.3em; margin: 0 0 .5em 0; }
h2 { font-size: 1.05em; margin: 1em 0 .3em 0; }
table { border-collapse: collapse; font-size: .85em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: right; }
th { background: #eee; }
td.l, th.l { text-align: left; }
tr.served { color: #999; }
tr.withdrawn { color: #b44; text-decoration: line-through; }
tr.next { background: #dfd; }
.images img { width: 48%; max-width: 960px; border: 1px solid #ccc; margin-right: 1%; background: #000; }
.row { display: flex; flex-wrap: wrap; gap: 2em; }
#conn.bad { color: #b00; }
.warning { color: #a60; }
.error, .critical { color: #b00; }
</style>
</head>
<body>
<h1>binpick <span id="cell"></span> <small id="conn">connecting…</small></h1>
<div class="images">
  <img id="depth" alt="depth image (no capture yet)">
  <img id="intensity" alt="intensity image (no capture yet)">
</div>
<div class="row">
<div>
<h2>Grasp queue <span id="queue-summary"></span></h2>
<table id="queue">
<thead><tr><th>#</th><th class="l">state</th><th>class</th><th>instance</th><th>score</th>
<th>x (m)</th><th>y (m)</th><th>z (m)</th></tr></thead>
<tbody></tbody>
</table>
<h2>Latest detection</h2>
<table id="detection"><tbody></tbody></table>
</div>
<div>
<h2>Stage latency</h2>
<table id="stages"><thead><tr><th class="l">stage</th><th>ms</th></tr></thead><tbody></tbody></table>
<h2>Tasks</h2>
<table id="tasks"><thead><tr><th>id</th><th class="l">name</th><th>grasps left</th></tr></thead><tbody></tbody></table>
<h2>Calibration</h2>
<table id="calibration"><tbody></tbody></table>
</div>
</div>
<h2>Robots</h2>
<table id="robots">
<thead><tr><th class="l">peer</th><th class="l">state</th><th class="l">last seen</th><th>answers</th>
<th>last command / status</th><th>x (m)</th><th>y (m)</th><th>z (m)</th>
<th class="l">quaternion (w x y z)</th></tr></thead>
<tbody></tbody>
</table>
<h2>Failed picks reported by robots</h2>
<table id="failed-picks">
<thead><tr><th>task</th><th class="l">class</th><th class="l">grasp</th><th>failures</th>
<th>spots refused</th><th class="l">last reason</th><th class="l">last robot</th><th class="l">last time</th></tr></thead>
<tbody></tbody>
</table>
<h2>Recent warnings and errors</h2>
<table id="errors"><thead><tr><th class="l">time</th><th class="l">level</th><th class="l">message</th></tr></thead><tbody></tbody></table>
<script>
"use strict";
let lastSeq = -1;
function cell(tr, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  tr.appendChild(td);
}
function fill(id, rows) {
  const body = document.querySelector("#" + id + " tbody");
  body.replaceChildren(...rows);
}
function row(values, cls) {
  const tr = document.createElement("tr");
  if (cls) tr.className = cls;
  values.forEach(v => cell(tr, v[0], v[1]));
  return tr;
}
const f3 = x => Number(x).toFixed(3);
function render(s) {
  document.getElementById("cell").textContent = "— cell " + s.cell;
  const q = s.queue;
  const grasps = q ? q.grasps : [];
  document.getElementById("queue-summary").textContent =
      q ? "(task " + q.task + ": " + q.remaining + " of " + q.total + " left)" : "(no detection yet)";
  fill("queue", grasps.map(g => {
    const tr = row([[g.index], [g.state, "l"], [g.class || g.class_id], [g.instance_id],
                    [Number(g.score).toFixed(3)], [f3(g.position_m[0])], [f3(g.position_m[1])],
                    [f3(g.position_m[2])]], "grasp " + g.state);
    tr.dataset.index = g.index;
    return tr;
  }));
  const d = s.detection;
  const det = d ? [["sequence", d.seq], ["task", d.task], ["time", d.time], ["outcome", d.outcome],
                   ["parts detected", d.detections], ["ROI points", d.roi_points],
                   ["capture ms", Number(d.capture_ms).toFixed(1)],
                   ["plan ms", Number(d.plan_ms).toFixed(1)],
                   ["capture status", d.capture_status || "ok"],
                   ["plan status", d.plan_status || "ok"], ["message", d.message]] : [];
  if (d && d.bin) {
    det.push(["bin", d.bin.found ? Number(d.bin.offset_mm).toFixed(1) + " mm / " +
                                       Number(d.bin.offset_deg).toFixed(2) + " deg from nominal" +
                                       (d.bin.warning ? " (WARNING: beyond bin.detect_warn)" : "")
                                 : "not found (" + d.bin.reason + "): nominal pose used"]);
  }
  if (d && d.fill) {
    det.push(["fill level", "mean " + (1000 * d.fill.mean_height_m).toFixed(0) + " mm, max " +
                            (1000 * d.fill.max_height_m).toFixed(0) + " mm, " +
                            (100 * d.fill.occupied_fraction).toFixed(0) + "% of the floor occupied"]);
  }
  fill("detection", det.map(r => row([[r[0], "l"], [r[1], "l"]])));
  const stages = d ? d.stages.slice() : [];
  if (d) {
    stages.unshift({stage: "capture", ms: d.capture_ms});
    stages.push({stage: "plan (total)", ms: d.plan_ms});
  }
  fill("stages", stages.map(st => row([[st.stage, "l"], [Number(st.ms).toFixed(1)]])));
  fill("tasks", s.tasks.map(t => row([[t.id], [t.name, "l"],
                                      [t.queue_size === undefined ? "" : t.queue_size]])));
  fill("calibration", s.calibration.map(c => row([[c.name, "l"], [c.value, "l"]])));
  fill("robots", s.robots.map(r => {
    const p = r.pose;
    return row([[r.peer, "l"], [r.idle ? "idle" : "active", "l"], [r.last_seen, "l"], [r.answers],
                [r.last_command + " / " + r.last_status],
                [p ? f3(p.position_m[0]) : ""], [p ? f3(p.position_m[1]) : ""],
                [p ? f3(p.position_m[2]) : ""],
                [p ? p.quaternion_wxyz.map(f3).join(" ") : "", "l"]], "robot");
  }));
  fill("failed-picks", (s.failed_picks || []).map(p =>
      row([[p.task], [p.class, "l"], [p.grasp, "l"], [p.failures], [p.spots_refused],
           [p.last_reason, "l"], [p.last_peer, "l"], [p.last_time, "l"]])));
  fill("errors", s.errors.slice().reverse().map(e =>
      row([[e.time, "l"], [e.level, "l " + e.level], [e.message, "l"]])));
  const seq = d ? d.seq : -1;
  const served = q ? q.total - q.remaining : 0;
  const key = seq + ":" + served;
  if (key !== lastSeq) {
    lastSeq = key;
    for (const name of ["depth", "intensity"]) {
      const img = document.getElementById(name);
      if (d) img.src = "/api/image/" + name + ".png?seq=" + key;
    }
  }
}
async function poll() {
  const conn = document.getElementById("conn");
  try {
    const res = await fetch("/api/status", {cache: "no-store"});
    if (!res.ok) throw new Error("HTTP " + res.status);
    render(await res.json());
    conn.textContent = "live";
    conn.className = "";
  } catch (e) {
    conn.textContent = "disconnected (" + e.message + ")";
    conn.className = "bad";
  }
  setTimeout(poll, 1000);
}
poll();
</script>
</body>
</html>
)HTML";

}  // namespace

std::string_view StatusPageHtml() { return kStatusPage; }

}  // namespace bp::internal
