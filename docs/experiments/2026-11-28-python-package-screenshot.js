// The example workflow loaded into a running ComfyUI's page, as a screenshot (headless
// Debian chromium through playwright-core from npm). Usage, with ComfyUI on PORT:
//   node docs/experiments/2026-11-28-python-package-screenshot.js PORT comfyui/example_workflow_api.json OUT.png
const { chromium } = require('playwright-core');
const fs = require('fs');
(async () => {
  const wf = JSON.parse(fs.readFileSync(process.argv[3], 'utf8'));
  const browser = await chromium.launch({ executablePath: '/usr/bin/chromium',
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
           '--disable-background-networking', '--disable-component-update', '--disable-sync'] });
  const page = await browser.newPage({ viewport: { width: 1600, height: 900 } });
  for (let i = 0; i < 120; i++) {
    try { await page.goto('http://127.0.0.1:' + process.argv[2] + '/', { timeout: 5000 }); break; }
    catch (e) { await new Promise(r => setTimeout(r, 1000)); }
  }
  await page.waitForFunction(() => window.app && window.app.graph, null, { timeout: 60000 });
  await page.evaluate(async (wf) => { await window.app.loadApiJson(wf, 'matup_example.json'); }, wf);
  await page.waitForTimeout(3000);
  await page.keyboard.press('Escape');
  await page.waitForTimeout(500);
  await page.evaluate(() => { document.querySelectorAll('.p-dialog-mask').forEach(e => e.remove()); });
  await page.evaluate(() => { const c = window.app.canvas; c.ds.scale = 0.75; c.ds.offset = [80, 40]; c.setDirty(true, true); });
  await page.waitForTimeout(1500);
  await page.screenshot({ path: process.argv[4] });
  await browser.close();
})().catch(e => { console.error(e); process.exit(1); });
