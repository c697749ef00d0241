// Opens a page in the system's headless Chromium (puppeteer-core, no browser download), waits until
// the page sets window.denserReady (all tiles loaded and drawn), and saves a PNG screenshot.
// Used by tests/export_formats.rs: node tools/web/screenshot.mjs URL OUT.png CHROMIUM [TIMEOUT_MS]
import puppeteer from 'puppeteer-core';
const [url, out, executablePath, timeoutMs] = process.argv.slice(2);
const browser = await puppeteer.launch({
  executablePath,
  headless: true,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--hide-scrollbars'],
  defaultViewport: { width: 800, height: 600 },
});
try {
  const page = await browser.newPage();
  page.on('console', (m) => console.log(`page: ${m.text()}`));
  page.on('pageerror', (e) => console.log(`page error: ${e.message}`));
  await page.goto(url, { waitUntil: 'load' });
  await page.waitForFunction('window.denserReady === true', { timeout: Number(timeoutMs || 60000), polling: 200 });
  await page.screenshot({ path: out });
  console.log(await page.evaluate('window.denserStats'));
} finally {
  await browser.close();
}
