/* The design explorer's own script (eval/design/explorer.py writes it into explorer.html).
   EXPLORER holds the designs: {name, kind, row, file, toml, sketch, profile, reason}, the nominal first. */
"use strict";

(function () {
  const designs = EXPLORER.designs;
  const nominal = designs[0];
  const front = document.getElementById("front");
  const parallel = document.getElementById("parallel");
  const config = { displayModeBar: false, responsive: true };
  const jointColours = ["#1f77b4", "#ff7f0e", "#2ca02c"];

  function format(value) {
    if (value === null || value === undefined) return "–";
    if (typeof value !== "number") return String(value);
    return Number.isInteger(value) ? String(value) : String(Number(value.toPrecision(4)));
  }

  function fillTable(table, rows) {
    table.replaceChildren(
      ...rows.map(([column, label, text]) => {
        const row = document.createElement("tr");
        row.dataset.column = column;
        const head = document.createElement("th");
        head.textContent = label;
        const cell = document.createElement("td");
        cell.textContent = text;
        row.append(head, cell);
        return row;
      }),
    );
  }

  function smallLayout(title, xTitle, yTitle) {
    return {
      title: { text: title, font: { size: 13 } },
      margin: { l: 55, r: 10, t: 30, b: 35 },
      xaxis: { title: { text: xTitle } },
      yaxis: { title: { text: yTitle } },
      legend: { font: { size: 9 } },
    };
  }

  function drawSketch(design) {
    const s = design.sketch;
    if (!s) {
      Plotly.react("sketch", [], smallLayout("no sketch: the design cannot reach the conveyor's centre", "", ""));
      return;
    }
    const line = (x, z, name, style) => ({ x, y: z, mode: "lines+markers", name, line: style, marker: { size: 5 } });
    const traces = [
      line([-s.ra, s.ra], [0, 0], "base", { color: "#555", width: 5 }),
      line([s.ra, s.elbow_x, s.rb], [0, s.elbow_z, s.platform_z], "arm and forearm", { color: "#1f77b4", width: 3 }),
      line([-s.ra, -s.elbow_x, -s.rb], [0, s.elbow_z, s.platform_z], "mirror", { color: "#9ecae1", width: 3 }),
      line([-s.rb, s.rb], [s.platform_z, s.platform_z], "platform", { color: "#d62728", width: 5 }),
    ];
    const reach = Math.max(s.elbow_x, s.ra) * 1.3;
    traces.push({
      x: [-reach, reach], y: [s.platform_z, s.platform_z], mode: "lines", name: "conveyor",
      line: { color: "#8c564b", dash: "dash" },
    });
    const row = design.row;
    const [diameter, height, top] = [row.cylinder_diameter_m, row.cylinder_height_m, row.cylinder_top_m];
    if ([diameter, height, top].every(Number.isFinite) && diameter > 0) {
      const r = diameter / 2;
      traces.push({
        x: [-r, r, r, -r, -r], y: [top, top, top - height, top - height, top], mode: "lines",
        name: "workspace cylinder", fill: "toself", line: { color: "#2ca02c" }, opacity: 0.4,
      });
    }
    const layout = smallLayout("side view of one chain at the conveyor's centre", "x (m)", "z (m)");
    layout.yaxis.scaleanchor = "x";
    Plotly.react("sketch", traces, layout, config);
  }

  function drawProfile(id, design, key, title, unit) {
    if (!design.profile) {
      Plotly.react(id, [], smallLayout(`${title}: no profile, the cycle leaves this design's reach`, "", ""));
      return;
    }
    const traces = [];
    for (let joint = 0; joint < 3; joint += 1) {
      if (design !== nominal && nominal.profile) {
        traces.push({
          x: nominal.profile.time, y: nominal.profile[key][joint], mode: "lines", name: `nominal ${joint + 1}`,
          line: { color: jointColours[joint], dash: "dot", width: 1 },
        });
      }
      traces.push({
        x: design.profile.time, y: design.profile[key][joint], mode: "lines", name: `joint ${joint + 1}`,
        line: { color: jointColours[joint], width: 2 },
      });
    }
    Plotly.react(id, traces, smallLayout(title, "time (s)", unit), config);
  }

  function selectDesign(index) {
    const design = designs[index];
    if (!design) throw new RangeError(`no design ${index}: the page has designs 0 to ${designs.length - 1}`);
    document.getElementById("design-name").textContent = design.name;
    document.getElementById("design-reason").textContent = design.reason ? `infeasible: ${design.reason}` : "";
    const geometry = EXPLORER.geometryColumns;
    fillTable(
      document.getElementById("geometry-table"),
      geometry.map((c) => [c, `${c} (mm)`, (1000 * design.row[c]).toFixed(1)]),
    );
    fillTable(
      document.getElementById("datasheet"),
      Object.keys(design.row)
        .filter((c) => !geometry.includes(c))
        .map((c) => [c, EXPLORER.labels[c], format(design.row[c])]),
    );
    drawSketch(design);
    drawProfile("torque-plot", design, "torque", "actuator torques (nominal dotted)", "N m");
    drawProfile("angle-plot", design, "theta", "motor angles (nominal dotted)", "rad");
    const link = document.getElementById("download");
    link.href = "data:text/plain;charset=utf-8," + encodeURIComponent(design.toml);
    link.download = design.file;
    link.textContent = `Download ${design.file}`;
    document.getElementById("design-select").value = String(index);
    Plotly.restyle(front, { x: [[design.row.workspace_m3]], y: [[design.row.peak_torque_nm]] }, [2]);
    Plotly.restyle(parallel, { "line.color": [designs.map((_, k) => (k === index ? 1 : 0))] }, [0]);
    document.body.dataset.selected = String(index);
  }

  function inBrush(value, range) {
    if (!range) return true;
    const ranges = Array.isArray(range[0]) ? range : [range];
    return ranges.some(([low, high]) => value >= low && value <= high);
  }

  function applyBrush() {
    const dimensions = parallel.data[0].dimensions;
    const kept = designs.map((_, k) => dimensions.every((d) => inBrush(d.values[k], d.constraintrange)));
    const opacity = (trace) => Array.from(trace.customdata, (k) => (kept[k] ? 1 : 0.15));
    Plotly.restyle(front, { "marker.opacity": [opacity(front.data[0]), opacity(front.data[1])] }, [0, 1]);
  }

  function dimension(column) {
    // the same axis as explorer.py's parallel_dimension
    return { label: EXPLORER.labels[column], values: designs.map((d) => d.row[column]), tickformat: ".4~g" };
  }

  function setAxes(columns) {
    // the axes kept keep their brushes
    const brushes = new Map(parallel.data[0].dimensions.map((d) => [d.label, d.constraintrange]));
    const dimensions = columns.map((column) => {
      const axis = dimension(column);
      if (brushes.get(axis.label)) axis.constraintrange = brushes.get(axis.label);
      return axis;
    });
    Plotly.restyle(parallel, { dimensions: [dimensions] }, [0]);
  }

  function fillAxisChoice() {
    const box = document.getElementById("axes");
    const shown = new Set(parallel.data[0].dimensions.map((d) => d.label));
    const boxes = EXPLORER.parallelColumns.map((column) => {
      const input = document.createElement("input");
      input.type = "checkbox";
      input.value = column;
      input.checked = shown.has(EXPLORER.labels[column]);
      const label = document.createElement("label");
      label.append(input, ` ${EXPLORER.labels[column]}`);
      box.append(label);
      return input;
    });
    box.addEventListener("change", () => setAxes(boxes.filter((b) => b.checked).map((b) => b.value)));
  }

  function start() {
    const select = document.getElementById("design-select");
    designs.forEach((design, k) => select.add(new Option(design.name, String(k))));
    select.addEventListener("change", () => selectDesign(Number(select.value)));
    front.on("plotly_click", (event) => {
      const point = event.points.find((p) => p.customdata !== undefined);
      if (point) selectDesign(Number(point.customdata));
    });
    parallel.on("plotly_restyle", (update) => {
      if (!("line.color" in update[0])) applyBrush();
    });
    Plotly.Plots.resize(front); // drawn while the page was parsed, before the panel took its width
    fillAxisChoice();
    selectDesign(0);
    window.explorerReady = true;
  }

  window.selectDesign = selectDesign;
  window.addEventListener("load", start);
})();
