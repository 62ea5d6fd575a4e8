// The notebook microphone (dualtalker_lite/viz/microphone.py): an anywidget front end.
// Record -> getUserMedia + MediaRecorder (an AnalyserNode drives the level meter) -> Stop -> the browser decodes
// the recording and resamples it to 16 kHz mono with an OfflineAudioContext -> float32 little-endian bytes in the
// model's `audio` trait (one binary buffer) -> the kernel animates it. Nothing is fetched from anywhere.
// Traits read: sample_rate, max_seconds; written: audio, status (one line: what happened, or why not).

function resampleMono(buffer, rate) {
  // (channels x N at the buffer's rate) -> Float32Array at `rate`: the mean of the channels, resampled by the
  // browser's own resampler (an OfflineAudioContext rendering at the target rate)
  const n = Math.max(1, Math.ceil(buffer.duration * rate));
  const off = new OfflineAudioContext(1, n, rate);
  const src = off.createBufferSource();
  src.buffer = buffer;
  src.connect(off.destination);      // a 1-channel destination: the channels are mixed down (averaged) here
  src.start();
  return off.startRendering().then((out) => out.getChannelData(0).slice());
}

function render({ model, el }) {
  el.classList.add("dtl-microphone");
  el.innerHTML = `
    <div style="display:flex;gap:10px;align-items:center;font:13px system-ui,sans-serif;padding:4px 0">
      <button class="dtl-rec" style="min-width:90px;padding:3px 10px">&#9679; Record</button>
      <meter class="dtl-level" min="0" max="1" value="0" style="width:110px"></meter>
      <span class="dtl-time" style="font-variant-numeric:tabular-nums;min-width:48px">0.0 s</span>
      <span class="dtl-status" role="status"></span>
    </div>`;
  const button = el.querySelector(".dtl-rec"), meter = el.querySelector(".dtl-level");
  const clock = el.querySelector(".dtl-time"), statusEl = el.querySelector(".dtl-status");
  const say = (text, toKernel = true) => {
    statusEl.textContent = text;
    if (toKernel) { model.set("status", text); model.save_changes(); }
  };
  let rec = null;   // {stream, ctx, recorder, chunks, t0, timer, raf}

  const finish = async (chunks, type) => {
    const rate = model.get("sample_rate");
    say("converting the recording to " + rate / 1000 + " kHz...");
    const blob = new Blob(chunks, { type });
    const ctx = new AudioContext();
    try {
      const decoded = await ctx.decodeAudioData(await blob.arrayBuffer());
      const wave = await resampleMono(decoded, rate);
      model.set("audio", new DataView(wave.buffer));   // bytes: float32 LE (every browser is little-endian)
      say(`recorded ${(wave.length / rate).toFixed(1)} s, sent to the kernel`);
    } catch (e) {
      say("cannot decode the recording: " + (e && e.message || e));
    } finally {
      ctx.close();
    }
  };
  const stop = () => {
    if (!rec) return;
    const r = rec; rec = null;
    clearInterval(r.timer); cancelAnimationFrame(r.raf);
    meter.value = 0; button.innerHTML = "&#9679; Record";
    if (r.recorder.state !== "inactive") r.recorder.stop();   // -> onstop -> finish
    r.stream.getTracks().forEach((t) => t.stop());
    r.ctx.close();
  };
  const start = async () => {
    let stream;
    try {
      stream = await navigator.mediaDevices.getUserMedia(
        { audio: { channelCount: 1, echoCancellation: false, noiseSuppression: false, autoGainControl: false } });
    } catch (e) {
      const denied = e && (e.name === "NotAllowedError" || e.name === "SecurityError");
      say(denied ? "No microphone permission: allow the microphone for this page, then press Record again."
                 : "cannot open the microphone: " + (e && e.message || e));
      return;
    }
    const ctx = new AudioContext();
    const analyser = ctx.createAnalyser();
    analyser.fftSize = 1024;
    ctx.createMediaStreamSource(stream).connect(analyser);     // the level meter only
    const chunks = [];
    const recorder = new MediaRecorder(stream);
    recorder.ondataavailable = (e) => { if (e.data && e.data.size) chunks.push(e.data); };
    recorder.onstop = () => finish(chunks, recorder.mimeType);
    const level = new Float32Array(analyser.fftSize);
    const t0 = performance.now(), max = model.get("max_seconds");
    const draw = () => {
      analyser.getFloatTimeDomainData(level);
      let sq = 0;
      for (const v of level) sq += v * v;
      meter.value = Math.min(1, 4 * Math.sqrt(sq / level.length));
      if (rec) rec.raf = requestAnimationFrame(draw);
    };
    const timer = setInterval(() => {
      const s = (performance.now() - t0) / 1000;
      clock.textContent = s.toFixed(1) + " s";
      if (s >= max) { say(`stopped at ${max} s (the longest recording)`, false); stop(); }
    }, 100);
    rec = { stream, ctx, recorder, chunks, t0, timer, raf: 0 };
    recorder.start(250);
    button.innerHTML = "&#9632; Stop";
    say("recording: speak, then press Stop");
    draw();
  };
  button.onclick = () => { if (rec) stop(); else start(); };
  const onStatus = () => { statusEl.textContent = model.get("status"); };
  model.on("change:status", onStatus);
  onStatus();
  return () => { model.off("change:status", onStatus); stop(); };
}

export default { render };
