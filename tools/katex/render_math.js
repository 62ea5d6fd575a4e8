// Render math with KaTeX as JupyterLab's KaTeX renderer would; report every failure.
// stdin: JSON [{"where": "...", "tex": "...", "display": true|false}, ...]
// stdout: JSON [{"where": "...", "tex": "...", "error": "..."}] (empty list: everything rendered)
// Strictness: KaTeX's parse errors always fail; of its "strict" warnings, only those that change what is shown
// fail (see STRICT_FAILS), the rest (e.g. Unicode text in math, which MathJax and KaTeX both render) pass.
"use strict";
const path = require("path");
const katex = require(path.join(__dirname, "node_modules", "katex"));

const STRICT_FAILS = new Set(["commentAtEnd", "newLineInDisplayMode", "htmlExtension"]);

let input = "";
process.stdin.on("data", (chunk) => (input += chunk));
process.stdin.on("end", () => {
  const failures = [];
  for (const item of JSON.parse(input)) {
    let warned = null;
    try {
      katex.renderToString(item.tex, {
        displayMode: item.display, throwOnError: true, output: "html",
        strict: (code, message) => {
          if (STRICT_FAILS.has(code) && warned === null) warned = `${code}: ${message}`;
          return "ignore";
        },
      });
      if (warned !== null) failures.push({ where: item.where, tex: item.tex, error: warned });
    } catch (e) {
      failures.push({ where: item.where, tex: item.tex, error: String(e.message || e) });
    }
  }
  process.stdout.write(JSON.stringify(failures));
});
