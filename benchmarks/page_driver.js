// Drives a pghm web page for the tests and benchmarks (benchmarks/browser.py puts it after the
// player with a plan): draws the plan's shots and keeps each as a PNG, times every frame of the
// motion once through, and writes the results as JSON into the pre element "pghm-result", which headless
// Chromium's --dump-dom prints.
"use strict";

(function () {
  const plan = JSON.parse(document.getElementById("pghm-plan").textContent);
  const player = window.pghmPlayer;
  const canvas = document.getElementById("view");
  const result = { firstFrameMs: player.firstFrameMs, accumulation: player.accumulation, frames: player.frames };
  player.resize(plan.width, plan.height);
  if (plan.background) player.setBackground(plan.background);
  result.shots = plan.shots.map((shot) => {
    player.seek(shot.frame);
    player.setView({ yaw: shot.yaw || 0, pitch: shot.pitch || 0, zoom: shot.zoom || 1 });
    const ms = player.render(shot.times || 1);
    return { ...shot, ms, primitive: player.primitive, png: canvas.toDataURL("image/png") };
  });
  player.setView({ yaw: 0, pitch: 0, zoom: 1 });
  if (plan.loop) {
    result.frameMs = [];
    for (let frame = 0; frame < player.frames; frame++) {
      player.seek(frame);
      result.frameMs.push(player.render());
    }
  }
  const out = document.createElement("pre");
  out.id = "pghm-result";
  out.textContent = JSON.stringify(result);
  document.body.appendChild(out);
})();
