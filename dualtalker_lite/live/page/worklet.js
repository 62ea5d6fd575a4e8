// AudioWorklet: the context's input (microphone or a file) -> 16 kHz mono int16, posted to the page in pieces of
// processorOptions.pieceMs (the server's /mesh "piece_ms": 100 ms for hama, 40 ms for the student, whose latency
// the piece's wait is a large part of) with the block's RMS level. The page asks for a 16 kHz AudioContext; where the browser runs it at another rate,
// the samples are resampled here by averaging each output sample's span of input samples (a box low-pass: crude,
// but the recogniser hears telephone-band speech well).
class PcmSender extends AudioWorkletProcessor {
  constructor(options) {
    super();
    this.ratio = sampleRate / 16000;     // input samples per output sample
    this.acc = 0; this.accN = 0; this.pos = 0;
    const ms = (options && options.processorOptions && options.processorOptions.pieceMs) || 100;
    this.size = Math.max(160, Math.min(16000, Math.round(16 * ms)));     // samples per message (10 ms .. 1 s)
    this.out = new Int16Array(this.size); this.n = 0; this.sq = 0;
  }
  push(x) {
    const v = Math.max(-1, Math.min(1, x));
    this.out[this.n++] = Math.round(v * 32767); this.sq += v * v;
    if (this.n === this.out.length) {
      const rms = Math.sqrt(this.sq / this.n);
      this.port.postMessage({ pcm: this.out.buffer, rms }, [this.out.buffer]);
      this.out = new Int16Array(this.size); this.n = 0; this.sq = 0;
    }
  }
  process(inputs) {
    const ch = inputs[0] && inputs[0][0];
    if (!ch) return true;
    if (this.ratio === 1) { for (let i = 0; i < ch.length; i++) this.push(ch[i]); return true; }
    for (let i = 0; i < ch.length; i++) {      // box average over each output sample's span of input samples
      this.acc += ch[i]; this.accN++; this.pos += 1;
      if (this.pos >= this.ratio) { this.push(this.acc / this.accN); this.acc = 0; this.accN = 0; this.pos -= this.ratio; }
    }
    return true;
  }
}
registerProcessor('pcm-sender', PcmSender);
