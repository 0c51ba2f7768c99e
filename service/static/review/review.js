// lishield-guard reviewer page: POST the dropped image to /v1/review and show the answer.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const drop = $("drop"), fileInput = $("file"), token = $("token");
  token.value = sessionStorage.getItem("lishield-token") || "";
  token.addEventListener("change", () => sessionStorage.setItem("lishield-token", token.value));

  function show(el, on) { el.hidden = !on; }

  async function screen(file) {
    show($("error"), false);
    show($("busy"), true);
    document.body.dataset.state = "busy";
    $("preview").src = URL.createObjectURL(file);
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
