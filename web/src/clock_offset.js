// The console's clock against this one, from pings, as NTP reads a server's: a ping leaves at t0
// on this clock, the console stamps it `server` on its own, and its pong comes back at t1. The
// console stamped it somewhere within [t0, t1]; taking the middle, the offset is off by at most
// half the round trip. The ping with the shortest round trip of the last `kept` therefore gives
// the offset: a console busy when a ping came stamps it late and answers late, so that ping's
// long round trip says not to believe it (a median of all of them followed a busy console).

export class ClockOffset {
  constructor(kept) {
    this.kept = kept;
    this.samples = []; // {offset, roundTrip} in ms, oldest first
  }

  // A ping sent at t0 and answered at t1 (this clock), stamped `server` by the console (ms).
  add(t0, server, t1) {
    if (![t0, server, t1].every(Number.isFinite) || t1 < t0) return;
    this.samples.push({ offset: server - (t0 + t1) / 2, roundTrip: t1 - t0 });
    if (this.samples.length > this.kept) this.samples.shift();
  }

  // Console clock - this clock (ms): the kept ping of the shortest round trip (0 before any).
  value() {
    if (!this.samples.length) return 0;
    return this.samples.reduce((best, s) => (s.roundTrip < best.roundTrip ? s : best)).offset;
  }
}
