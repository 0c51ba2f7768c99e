// lishield-guard reviewer page: POST the dropped image or clip to /v1/review and show the answer.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const drop = $("drop"), fileInput = $("file"), token = $("token");
  token.value = sessionStorage.getItem("lishield-token") || "";
  token.addEventListener("change", () => sessionStorage.setItem("lishield-token", token.value));

  function show(el, on) { el.hidden = !on; }

  const VIDEO_NAME = /\.(mp4|m4v|mov|webm|mkv)$/i;

  function preview(file) {
    const isVideo = file.type.startsWith("video/") || VIDEO_NAME.test(file.name);
    const [shown, hidden] = isVideo ? [$("preview-video"), $("preview")]
      : [$("preview"), $("preview-video")];
    hidden.removeAttribute("src");
    show(hidden, false);
    shown.src = URL.createObjectURL(file);
    show(shown, true);
  }

  // One row per screened frame of a video verdict (evidence.video.frames), deciding ones marked.
  function renderFrames(evidence) {
    const video = evidence && evidence.video;
    const body = $("frames").tBodies[0];
    body.replaceChildren();
    show($("frames-box"), Boolean(video));
    if (!video) return;
    const deciding = new Set(evidence.deciding_frames || []);
    $("frames-note").textContent = video.frames_screened + " frames screened (" + video.frames_decoded
      + " decoded), stopped: " + video.stop + "; clip logit " + Number(video.clip_logit).toFixed(2)
      + " against threshold " + Number(video.threshold_logit).toFixed(2) + ". Bold: deciding frames.";
    for (const f of video.frames) {
      const row = body.insertRow();
      if (deciding.has(f.index)) row.className = "deciding";
      const logit = f.logit === null || f.logit === undefined ? "-" : Number(f.logit).toFixed(2);
      for (const text of [f.index, Number(f.time_s).toFixed(3), logit, f.keyframe ? "yes" : "",
                          f.run, f.where || f.undetermined || ""]) {
        row.insertCell().textContent = String(text);
      }
    }
  }

  async function screen(file) {
    show($("error"), false);
    show($("busy"), true);
    document.body.dataset.state = "busy";
    preview(file);
    $("file-name").textContent = file.name + " (" + file.size.toLocaleString() + " bytes)";
    const body = new FormData();
    body.append("file", file, file.name);
    const headers = {};
    if (token.value) headers["Authorization"] = "Bearer " + token.value;
    try {
      const r = await fetch("/v1/review", { method: "POST", body, headers });
      const data = await r.json();
      if (!r.ok) {
        const hint = r.status === 401 ? " Enter the service's bearer token above." : "";
        throw new Error((data.message || r.statusText) + " [" + (data.code || r.status) + "]" + hint);
      }
      render(data);
    } catch (err) {
      show($("result"), false);
      $("error").textContent = "Could not screen " + file.name + ": " + err.message;
      show($("error"), true);
      document.body.dataset.state = "error";
    } finally {
      show($("busy"), false);
    }
  }

  function render(data) {
    const title = $("title");
    title.textContent = data.title;
    title.dataset.status = data.status;
    const v = data.verdict;
    $("status-line").textContent = "Status: " + data.status + (v.policy ? " (policy " + v.policy + ")" : "")
      + ", profile " + v.profile + ", score " + Number(v.score).toFixed(3);
    $("reason").textContent = "Why: " + data.reason;
    const fig = $("figure");
    if (data.figure_png_base64) {
      fig.src = "data:image/png;base64," + data.figure_png_base64;
      show(fig, true);
      $("figure-caption").textContent = data.figure_caption || "";  // follows the deciding stage
      $("figure-caption").hidden = false;
    } else {
      fig.removeAttribute("src");
      show(fig, false);
      $("figure-caption").textContent = "No figure: " + (data.figure_error || "not available");
    }
    renderFrames(v.evidence);
    $("json").textContent = JSON.stringify(v, null, 2);
    show($("result"), true);
    document.body.dataset.state = "done";
  }

  drop.addEventListener("click", () => fileInput.click());
  drop.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") fileInput.click(); });
  fileInput.addEventListener("change", () => { if (fileInput.files.length) screen(fileInput.files[0]); });
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    if (e.dataTransfer.files.length) screen(e.dataTransfer.files[0]);
  });
})();
