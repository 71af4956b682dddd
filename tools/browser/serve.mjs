// Starts `skybake serve` on a loopback port with a scratch cache directory, for the browser
// tests; resolves to { child, addr, cache } once the server logs its address.
import { spawn } from "node:child_process";
import { mkdtempSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";

export function startServer(binary) {
  const cache = mkdtempSync(join(tmpdir(), "skybake-viewer-"));
  const child = spawn(binary, ["serve", "--bind", "127.0.0.1:0", "--cache-dir", cache], {
    stdio: ["ignore", "ignore", "pipe"],
  });
  return new Promise((resolveAddr, reject) => {
    let err = "";
    const timer = setTimeout(() => reject(new Error(`server did not start: ${err}`)), 30000);
    child.stderr.on("data", (d) => {
      err += d.toString();
      const m = err.match(/listening on (\S+)/);
      if (m) {
        clearTimeout(timer);
        resolveAddr({ child, addr: m[1], cache });
      }
    });
    child.on("exit", (code) => reject(new Error(`server exited with ${code}: ${err}`)));
  });
}
