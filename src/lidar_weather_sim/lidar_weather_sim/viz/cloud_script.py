"""The page script of ``render --html`` (JavaScript; kept in a module so any install carries it).

``__DATA__`` is replaced by the run's JSON (:func:`lidar_weather_sim.viz.html.write_html`); plotly's
``to_html`` replaces ``{plot_id}`` by the plot's div id and runs the script once the empty plot exists.
It decodes the frames (int16 cm coordinates, uint8 fields, uint16 mm EPW), builds the controls (colour
field, frame slider, a caption; ``#color=F&frame=K`` in the URL picks them) and redraws with ``Plotly.react`` (the camera is kept: ``uirevision``).
"""

SCRIPT = r"""
(function () {
  const D = __DATA__;
  const div = document.getElementById('{plot_id}');
  function decode(text, Type) {
    const bin = atob(text), bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }
  const frames = D.frames.map(function (f) {
    const xyz = decode(f.xyz, Int16Array), n = f.n;
    const x = new Float32Array(n), y = new Float32Array(n), z = new Float32Array(n), v = {};
    const distance = new Float32Array(n);
    for (let i = 0; i < n; i++) {
      x[i] = xyz[3 * i] / 100; y[i] = xyz[3 * i + 1] / 100; z[i] = xyz[3 * i + 2] / 100;
      distance[i] = Math.hypot(x[i], y[i], z[i]);
    }
    for (const name in f.fields) {
      const raw = decode(f.fields[name], name === 'epw' ? Uint16Array : Uint8Array);
      v[name] = name === 'epw' ? Float32Array.from(raw, function (q) { return q / 1000; }) : raw;
    }
    v.distance = distance;
    return {index: f.index, time: f.time, total: f.total, n: n, frame_id: f.frame_id, x: x, y: y, z: z, v: v,
            actors: f.actors};
  });
  const specs = {};
  D.specs.forEach(function (s) { specs[s.field] = s; });

  function pick(f, keep) {
    const x = [], y = [], z = [];
    for (let i = 0; i < f.n; i++) if (keep(i)) { x.push(f.x[i]); y.push(f.y[i]); z.push(f.z[i]); }
    return {x: x, y: y, z: z};
  }
  function cloudTraces(f, spec) {
    const values = f.v[spec.field];
    if (spec.categories) {
      const codes = spec.categories.map(function (c) { return c.code; });
      const last = codes[codes.length - 1];
      const category = function (value) {  // echo: 4 and more share the last; unknown labels are 0
        if (spec.field === 'echo') return Math.min(Math.max(value, 1), last);
        return codes.indexOf(value) >= 0 ? value : 0;
      };
      return spec.categories.map(function (c) {
        const xyz = pick(f, function (i) { return category(values[i]) === c.code; });
        return Object.assign({type: 'scatter3d', mode: 'markers', name: c.code + ' ' + c.name,
                              marker: {size: 2, color: c.color}, hoverinfo: 'x+y+z+name'}, xyz);
      });
    }
    return [{type: 'scatter3d', mode: 'markers', name: spec.title, x: f.x, y: f.y, z: f.z, showlegend: false,
             marker: {size: 2, color: values, cmin: spec.vmin, cmax: spec.vmax, colorscale: spec.colorscale,
                      showscale: true, colorbar: {title: {text: spec.title}, len: 0.6}},
             hovertemplate: spec.field + ' %{marker.color:.3f}<extra></extra>'}];
  }
  function markerTraces(f) {
    const ego = {type: 'scatter3d', mode: 'lines+markers', name: 'ego: sensor origin, +x', x: [0, 2], y: [0, 0],
                 z: [0, 0], marker: {size: [6, 0], color: '#ffffff', symbol: 'diamond'},
                 line: {color: '#ffffff', width: 4}};
    const box = {x: [], y: [], z: []}, frame = {x: [], y: [], z: []};
    f.actors.forEach(function (a) {
      if (a.edges) {
        a.edges.forEach(function (e) {
          box.x.push(e[0][0], e[1][0], null); box.y.push(e[0][1], e[1][1], null); box.z.push(e[0][2], e[1][2], null);
        });
      } else {
        frame.x.push(a.origin[0], a.ahead[0], null); frame.y.push(a.origin[1], a.ahead[1], null);
        frame.z.push(a.origin[2], a.ahead[2], null);
      }
    });
    const out = [ego];
    if (box.x.length) out.push(Object.assign({type: 'scatter3d', mode: 'lines', name: 'actor box (scenario size)',
                                              line: {color: '#ff3cff', width: 4}}, box));
    if (frame.x.length) out.push(Object.assign({type: 'scatter3d', mode: 'lines+markers',
                                                name: 'actor frame (size unknown)', line: {color: '#ff3cff', width: 4},
                                                marker: {size: 4, color: '#ff3cff'}}, frame));
    return out;
  }

  const bar = document.createElement('div');
  bar.id = 'lws-controls';
  bar.style.cssText = 'font: 14px sans-serif; color: #e0e0e0; background: #141418; padding: 6px 10px;';
  const select = document.createElement('select');
  D.specs.forEach(function (s) {
    const o = document.createElement('option'); o.value = s.field; o.textContent = s.field; select.appendChild(o);
  });
  const hash = new URLSearchParams(location.hash.slice(1));  // page.html#color=intensity&frame=3
  select.value = specs[hash.get('color')] ? hash.get('color') : D.color;
  const slider = document.createElement('input');
  slider.type = 'range'; slider.min = 0; slider.max = Math.max(0, frames.length - 1); slider.value = Math.min(+hash.get('frame') || 0, frames.length - 1);
  slider.style.width = '40%'; slider.id = 'lws-frame';
  const caption = document.createElement('span');
  bar.append('colour by ', select, '  frame ', slider, ' ', caption);
  div.parentNode.insertBefore(bar, div);
  document.body.style.background = '#141418';

  function draw() {
    const f = frames[+slider.value];
    if (!f) { caption.textContent = 'no frame'; return; }
    caption.textContent = 'frame ' + f.index + ', t = ' + f.time.toFixed(3) + ' s, ' + f.n + ' of ' + f.total +
      ' points shown (at most ' + D.max_points + ' per frame), ' + f.frame_id + ' frame';
    Plotly.react(div, cloudTraces(f, specs[select.value]).concat(markerTraces(f)), div.layout);
  }
  select.addEventListener('change', draw);
  slider.addEventListener('input', draw);
  draw();
})();
"""
