// TripleSumo match page: draws the scene the page's JSON describes (read from MuJoCo's compiled model) and
// moves each body to its recorded pose (MuJoCo's xpos/xquat, float32) frame by frame, with three.js.
// URL options: ?frame=N (show step N, paused) &camera=overview|top|follow:AGENT &bare=1 (canvas only)
// &flat=1 (unlit colours). window.__ready is true once the first frame is drawn.
(function () {
  'use strict';
  const D = JSON.parse(document.getElementById('match-data').textContent);
  const params = new URLSearchParams(window.location.search);
  const bare = params.get('bare') === '1';
  const flat = params.get('flat') === '1';
  if (bare) document.body.classList.add('bare');

  function floats(b64) {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    return new Float32Array(bytes.buffer);
  }
  const poses = floats(D.poses);
  const nBodies = D.bodies.length;
  const nAgents = D.agents.length;
  const terms = D.terms;
  const rewards = D.rewards ? floats(D.rewards) : null;

  // ---------------------------------------------------------------- page layout
  function el(tag, attrs, parent) {
    const e = document.createElement(tag);
    Object.assign(e, attrs || {});
    if (parent) parent.appendChild(e);
    return e;
  }
  const view = el('div', { id: 'view' }, document.body);
  const info = el('div', { id: 'info' }, document.body);
  el('h1', { textContent: D.title }, info);
  const stepLine = el('div', { className: 'step' }, info);
  const outcomeLine = el('div', { className: 'outcome' }, info);
  const who = el('div', {}, info);
  D.agents.forEach((a) => {
    const row = el('div', {}, who);
    const sw = el('span', { textContent: '\u25A0 ' }, row);
    sw.style.color = css(a.rgba);
    el('span', { textContent: a.name + ' (' + a.team + ')' + (a.policy ? ': ' + a.policy : '') +
      (a.outcome ? ' \u2192 ' + a.outcome : '') }, row);
  });
  el('div', { textContent: 'seed ' + D.seed + ', ' + D.steps + ' steps at ' + Math.round(D.fps) + ' steps/s' +
    (D.verified ? ', re-simulated bit for bit' : ', recorded states (not re-simulated)') }, info);
  el('div', { id: 'help', textContent:
    'space: play/pause \u00b7 \u2190 \u2192: frame \u00b7 drag: orbit \u00b7 right-drag: pan \u00b7 wheel: zoom' },
  document.body);

  const bar = el('div', { id: 'bar' }, document.body);
  const playBtn = el('button', { textContent: '\u25B6 play', title: 'play / pause (space)' }, bar);
  const backBtn = el('button', { textContent: '\u25C0|', title: 'previous frame (\u2190)' }, bar);
  const fwdBtn = el('button', { textContent: '|\u25B6', title: 'next frame (\u2192)' }, bar);
  const slider = el('input', { type: 'range', min: 0, max: D.frames.length - 1, value: 0, step: 1 }, bar);
  const frameLabel = el('span', { className: 'frame' }, bar);
  const speedSel = el('select', { title: 'speed' }, bar);
  [0.1, 0.25, 0.5, 1, 2, 4].forEach((s) => el('option', { value: s, textContent: s + '\u00d7', selected: s === 1 },
    speedSel));
  const camSel = el('select', { title: 'camera' }, bar);
  const termsBtn = el('button', { textContent: 'rewards', title: 'show or hide the reward terms' }, bar);
  const camChoices = [...Object.keys(D.cameras), 'free', ...D.agents.map((a) => 'follow:' + a.name)];
  camChoices.forEach((c) => el('option', { value: c, textContent: c === 'top' ? 'top-down' : c.replace('follow:',
    'follow ') }, camSel));

  function css(rgba) {
    return 'rgb(' + rgba.slice(0, 3).map((c) => Math.round(255 * c)).join(',') + ')';
  }
  function srgb(rgba) {
    return new THREE.Color().setRGB(rgba[0], rgba[1], rgba[2], THREE.SRGBColorSpace);
  }

  // ---------------------------------------------------------------- three.js scene from the model
  const renderer = new THREE.WebGLRenderer({ antialias: !flat, preserveDrawingBuffer: true });
  renderer.setPixelRatio(bare ? 1 : window.devicePixelRatio);
  view.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = flat ? new THREE.Color(0, 0, 0) : srgb([0.32, 0.34, 0.42]);
  const camera = new THREE.PerspectiveCamera(45, 1, D.znear, D.zfar);
  camera.up.set(0, 0, 1);
  scene.add(camera);
  if (!flat) {
    scene.add(new THREE.AmbientLight(srgb(D.headlight.ambient.concat([1])), Math.PI));
    const head = new THREE.DirectionalLight(srgb(D.headlight.diffuse.concat([1])), Math.PI);
    head.position.set(0, 0, 1); // a headlight: shines along the camera's view
    camera.add(head);
    camera.add(head.target);
    head.target.position.set(0, 0, -1);
    D.lights.forEach((l) => {
      const light = new THREE.DirectionalLight(srgb(l.diffuse.concat([1])), Math.PI);
      light.position.set(-l.dir[0], -l.dir[1], -l.dir[2]);
      scene.add(light);
    });
  }
  function texture(t) { // a plane's texture from the model (MuJoCo's pixels, sampled down), repeated as there
    const rgb = Uint8Array.from(atob(t.rgb), (c) => c.charCodeAt(0));
    const rgba = new Uint8Array(t.width * t.height * 4);
    for (let i = 0; i < t.width * t.height; i++) {
      rgba.set(rgb.subarray(3 * i, 3 * i + 3), 4 * i);
      rgba[4 * i + 3] = 255;
    }
    const tex = new THREE.DataTexture(rgba, t.width, t.height, THREE.RGBAFormat);
    tex.colorSpace = THREE.SRGBColorSpace;
    tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
    tex.magFilter = THREE.NearestFilter;
    tex.repeat.set(t.repeat[0], t.repeat[1]);
    tex.needsUpdate = true;
    return tex;
  }
  const bodies = D.bodies.map(() => {
    const g = new THREE.Group();
    scene.add(g);
    return g;
  });
  D.geoms.forEach((g) => {
    const s = g.size;
    let geo;
    if (g.type === 'sphere') geo = new THREE.SphereGeometry(s[0], 32, 16);
    else if (g.type === 'ellipsoid') geo = new THREE.SphereGeometry(1, 32, 16).scale(s[0], s[1], s[2]);
    else if (g.type === 'capsule') geo = new THREE.CapsuleGeometry(s[0], 2 * s[1], 8, 24).rotateX(Math.PI / 2);
    else if (g.type === 'cylinder') geo = new THREE.CylinderGeometry(s[0], s[0], 2 * s[1], 32).rotateX(Math.PI / 2);
    else if (g.type === 'box') geo = new THREE.BoxGeometry(2 * s[0], 2 * s[1], 2 * s[2]);
    else if (g.type === 'plane') geo = new THREE.PlaneGeometry(2 * (s[0] || 50), 2 * (s[1] || 50));
    else return;
    const colour = srgb(g.rgba);
    const mat = flat ? new THREE.MeshBasicMaterial({ color: colour })
      : g.texture ? new THREE.MeshLambertMaterial({ color: srgb(g.texture.rgba), map: texture(g.texture) })
      : g.type === 'plane' ? new THREE.MeshLambertMaterial({ color: colour })
        : new THREE.MeshPhongMaterial({ color: colour, shininess: 40, specular: new THREE.Color(0.15, 0.15, 0.15) });
    const mesh = new THREE.Mesh(geo, mat);
    mesh.position.set(g.pos[0], g.pos[1], g.pos[2]);
    mesh.quaternion.set(g.quat[1], g.quat[2], g.quat[3], g.quat[0]); // MuJoCo quaternions are (w, x, y, z)
    (g.body >= 0 ? bodies[g.body] : scene).add(mesh);
  });
  // each agent's torso: the body its label and the follow camera track
  const torso = D.agents.map((a) => D.bodies.indexOf(a.name + '/torso'));
  const labels = D.agents.map((a) => {
    const l = el('div', { className: 'label', textContent: a.name }, view);
    l.style.background = css(a.rgba);
    return l;
  });

  // ---------------------------------------------------------------- cameras
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.enableDamping = false;
  let follow = -1;
  const lastTorso = new THREE.Vector3();
  function useModelCamera(name) {
    const c = D.cameras[name];
    const m = c.mat;
    camera.fov = c.fovy;
    camera.position.set(c.pos[0], c.pos[1], c.pos[2]);
    const rot = new THREE.Matrix4().set(m[0], m[1], m[2], 0, m[3], m[4], m[5], 0, m[6], m[7], m[8], 0, 0, 0, 0, 1);
    camera.quaternion.setFromRotationMatrix(rot);
    camera.updateProjectionMatrix();
    // orbit about the point the view's axis meets the ring's surface (camera looks along its -z)
    const ahead = new THREE.Vector3(-m[2], -m[5], -m[8]);
    const t = ahead.z < -1e-6 ? (0.5 - c.pos[2]) / ahead.z : 5;
    controls.target.copy(camera.position).addScaledVector(ahead, t);
  }
  function torsoAt(k, f) {
    const o = (f * nBodies + torso[k]) * 7;
    return new THREE.Vector3(poses[o], poses[o + 1], poses[o + 2]);
  }
  function setCamera(choice) {
    follow = -1;
    if (D.cameras[choice]) useModelCamera(choice);
    else if (choice.startsWith('follow:')) {
      follow = D.agents.findIndex((a) => 'follow:' + a.name === choice);
      if (follow < 0) follow = -1;
      else {
        const p = torsoAt(follow, frame);
        camera.position.set(p.x - 1.8, p.y - 1.8, p.z + 1.6);
        controls.target.copy(p);
        lastTorso.copy(p);
        controls.update();
      }
    }
    camSel.value = choice;
  }

  // ---------------------------------------------------------------- rewards along the timeline
  const termColours = ['#ff8a65', '#4fc3f7', '#ba68c8', '#aed581', '#ffd54f', '#90a4ae'];
  const rewardPanels = [];
  if (!rewards || bare) termsBtn.style.display = 'none';
  if (rewards && !bare) {
    const box = el('div', { id: 'rewards' }, document.body);
    termsBtn.onclick = () => { box.style.display = box.style.display === 'none' ? '' : 'none'; };
    if (window.innerWidth < 760) box.style.display = 'none';
    el('div', { textContent: 'reward terms, summed from the start (line: this step)' }, box);
    for (let a = 0; a < nAgents; a++) {
      const row = el('div', { className: 'agent' }, box);
      const nm = el('div', { className: 'name', textContent: D.agents[a].name }, row);
      nm.style.color = css(D.agents[a].rgba);
      const cv = el('canvas', { width: 260, height: 44 }, row);
      const legend = el('div', { className: 'legend' }, row);
      // cumulative sums per term
      const cum = terms.map((_, k) => {
        const c = new Float32Array(D.steps + 1);
        for (let t = 0; t < D.steps; t++) c[t + 1] = c[t] + rewards[(t * nAgents + a) * terms.length + k];
        return c;
      });
      let lo = 0; let hi = 0;
      cum.forEach((c) => c.forEach((v) => { lo = Math.min(lo, v); hi = Math.max(hi, v); }));
      if (hi - lo < 1e-9) hi = lo + 1;
      cv.addEventListener('click', (ev) => {
        const step = Math.round(ev.offsetX / cv.width * D.steps);
        show(frameOfStep(step));
      });
      rewardPanels.push({ cv, legend, cum, lo, hi, a });
    }
  }
  function drawRewards(step) {
    rewardPanels.forEach((p) => {
      const ctx = p.cv.getContext('2d');
      const w = p.cv.width; const h = p.cv.height;
      ctx.clearRect(0, 0, w, h);
      const y = (v) => h - 3 - (v - p.lo) / (p.hi - p.lo) * (h - 6);
      ctx.strokeStyle = '#555a6e';
      ctx.beginPath(); ctx.moveTo(0, y(0)); ctx.lineTo(w, y(0)); ctx.stroke();
      p.cum.forEach((c, k) => {
        ctx.strokeStyle = termColours[k % termColours.length];
        ctx.beginPath();
        for (let t = 0; t <= D.steps; t++) {
          const x = t / Math.max(1, D.steps) * w;
          if (t === 0) ctx.moveTo(x, y(c[t])); else ctx.lineTo(x, y(c[t]));
        }
        ctx.stroke();
      });
      const x = step / Math.max(1, D.steps) * w;
      ctx.strokeStyle = '#fff';
      ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, h); ctx.stroke();
      const parts = terms.map((name, k) => {
        const now = step > 0 ? rewards[((step - 1) * nAgents + p.a) * terms.length + k] : 0;
        return '<span style="color:' + termColours[k % termColours.length] + '">' +
          name.replace('reward_', '').replace('_velocity', ' v') + ' ' + p.cum[k][step].toFixed(1) + ' (' + (now >= 0 ? '+' : '') +
          now.toFixed(2) + ')</span>';
      });
      p.legend.innerHTML = parts.join(' ');
    });
  }

  // ---------------------------------------------------------------- frames
  let frame = 0;
  function frameOfStep(step) {
    let best = 0;
    D.frames.forEach((s, i) => { if (Math.abs(s - step) < Math.abs(D.frames[best] - step)) best = i; });
    return best;
  }
  function pose(f) {
    for (let b = 0; b < nBodies; b++) {
      const o = (f * nBodies + b) * 7;
      bodies[b].position.set(poses[o], poses[o + 1], poses[o + 2]);
      bodies[b].quaternion.set(poses[o + 4], poses[o + 5], poses[o + 6], poses[o + 3]);
    }
  }
  function outcomeText(step) {
    const gone = D.agents.map((a, i) => D.out_of_ring[i].filter((s) => s <= step).length ? a.name : null)
      .filter((n) => n);
    const end = step >= D.steps ? 'final: ' + D.agents.map((a) => a.name + ' ' + (a.outcome || '?')).join(', ')
      : 'playing';
    return end + (gone.length ? ' \u00b7 out of the ring: ' + gone.join(', ') : '');
  }
  function show(f) {
    frame = Math.max(0, Math.min(D.frames.length - 1, f));
    const step = D.frames[frame];
    pose(frame);
    if (follow >= 0) {
      const p = torsoAt(follow, frame);
      const d = p.clone().sub(lastTorso);
      camera.position.add(d);
      controls.target.add(d);
      lastTorso.copy(p);
    }
    slider.value = frame;
    frameLabel.textContent = 'step ' + step + ' / ' + D.steps;
    stepLine.textContent = 'step ' + step + ' / ' + D.steps + '  (' + (step / D.fps).toFixed(2) + ' s)';
    outcomeLine.textContent = outcomeText(step);
    drawRewards(step);
    render();
  }
  const v = new THREE.Vector3();
  function render() {
    const w = view.clientWidth || window.innerWidth; const h = view.clientHeight || window.innerHeight;
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    renderer.render(scene, camera);
    D.agents.forEach((a, k) => {
      v.copy(torsoAt(k, frame)).setZ(torsoAt(k, frame).z + 0.45).project(camera);
      const l = labels[k];
      l.style.display = v.z < 1 ? '' : 'none';
      l.style.left = ((v.x + 1) / 2 * w) + 'px';
      l.style.top = ((1 - v.y) / 2 * h) + 'px';
    });
  }

  // ---------------------------------------------------------------- playback
  let playing = false; let speed = 1; let clock = 0; let last = 0;
  function setPlaying(on) {
    playing = on && D.frames.length > 1;
    playBtn.textContent = playing ? '\u275A\u275A pause' : '\u25B6 play';
    if (playing && frame >= D.frames.length - 1) show(0);
    clock = D.frames[frame] / D.fps;
    last = performance.now();
    if (playing) requestAnimationFrame(tick);
  }
  function tick(now) {
    if (!playing) return;
    clock += (now - last) / 1000 * speed;
    last = now;
    const f = frameOfStepFast(clock * D.fps);
    if (f !== frame) show(f);
    if (frame >= D.frames.length - 1) { setPlaying(false); return; }
    requestAnimationFrame(tick);
  }
  function frameOfStepFast(step) { // frames are sorted: the last kept frame at or before step
    let lo = 0; let hi = D.frames.length - 1;
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (D.frames[mid] <= step) lo = mid; else hi = mid - 1; }
    return lo;
  }
  playBtn.onclick = () => setPlaying(!playing);
  backBtn.onclick = () => { setPlaying(false); show(frame - 1); };
  fwdBtn.onclick = () => { setPlaying(false); show(frame + 1); };
  slider.oninput = () => { show(Number(slider.value)); clock = D.frames[frame] / D.fps; };
  speedSel.onchange = () => { speed = Number(speedSel.value); };
  camSel.onchange = () => { setCamera(camSel.value); render(); };
  controls.addEventListener('change', () => {
    if (camSel.value !== 'free' && follow < 0) camSel.value = 'free';
    render();
  });
  window.addEventListener('resize', render);
  window.addEventListener('keydown', (e) => {
    if (e.target.tagName === 'SELECT') return;
    if (e.key === ' ') { e.preventDefault(); setPlaying(!playing); }
    else if (e.key === 'ArrowLeft') { setPlaying(false); show(frame - 1); }
    else if (e.key === 'ArrowRight') { setPlaying(false); show(frame + 1); }
  });

  const askedStep = params.has('frame') ? Number(params.get('frame')) : 0;
  frame = frameOfStep(askedStep);
  setCamera(params.get('camera') || (D.cameras.overview ? 'overview' : camChoices[0]));
  show(frame);
  window.__ready = true;
  document.title = document.title + ' \u00b7 ready';
})();
