// The study pages' forms: every form with data-api posts its fields as JSON, in one request,
// to that address; the server answers {"next": url} (go there) or {"error": "..."} (shown on
// the page, nothing stored). A tracker file is read here and sent as text.
"use strict";

function showSources(form) {
  const chosen = form.querySelector("input[name=source]:checked");
  for (const box of form.querySelectorAll(".source")) {
    box.classList.toggle("on", chosen !== null && box.dataset.source === chosen.value);
  }
}

// The round's comfort item: "The round starts now" starts the round clock (performance.now(),
// the page's monotonic clock); each "Too close!" press is kept as seconds since that start, in
// the hidden too_close field (comma-separated, 3 decimals), sent with the round.
function comfortClock(box) {
  const start = box.querySelector("button.clock");
  const press = box.querySelector("button.too-close");
  const count = box.querySelector(".presses");
  const field = box.querySelector("input[name=too_close]");
  let t0 = null;
  const times = [];
  start.addEventListener("click", () => {
    t0 = performance.now();
    times.length = 0;
    field.value = "";
    start.textContent = "Restart the round clock";
    press.disabled = false;
    count.textContent = "clock running: no presses";
  });
  press.addEventListener("click", () => {
    if (t0 === null) return;
    times.push(((performance.now() - t0) / 1000).toFixed(3));
    field.value = times.join(",");
    count.textContent = times.length + (times.length === 1 ? " press, last at " : " presses, last at ")
      + times[times.length - 1] + " s";
  });
}

async function submitForm(form, event) {
  event.preventDefault();
  const error = form.querySelector(".error");
  const button = form.querySelector("button[type=submit]");
  const busy = form.querySelector(".busy");
  error.textContent = "";
  const fields = {};
  let tracker = null;
  for (const el of form.elements) {
    if (!el.name || el.disabled) continue;
    if (el.type === "file") {
      if (el.files.length) tracker = await el.files[0].text();
      continue;
    }
    if ((el.type === "radio" || el.type === "checkbox") && !el.checked) continue;
    fields[el.name] = el.value;
  }
  const body = { step: form.dataset.step, fields: fields };
  if (tracker !== null) body.tracker = tracker;
  button.disabled = true;
  if (busy) busy.textContent = form.dataset.busy || "saving…";
  try {
    const res = await fetch(form.dataset.api, {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify(body),
    });
    let answer = {};
    try { answer = await res.json(); } catch (e) { answer = {}; }
    if (res.ok && answer.next) {
      window.location.assign(answer.next);
      return;
    }
    error.textContent = answer.error || ("the server answered " + res.status);
  } catch (e) {
    error.textContent = "the server cannot be reached (" + e.message + "); nothing was lost: " +
      "restart it and reload this page";
  }
  button.disabled = false;
  if (busy) busy.textContent = "";
}

document.addEventListener("DOMContentLoaded", () => {
  for (const form of document.querySelectorAll("form[data-api]")) {
    form.addEventListener("submit", (ev) => submitForm(form, ev));
    // a message belongs to the answers it was about: gone once they change
    form.addEventListener("change", () => { form.querySelector(".error").textContent = ""; });
    for (const r of form.querySelectorAll("input[name=source]")) {
      r.addEventListener("change", () => showSources(form));
    }
    showSources(form);
  }
  for (const box of document.querySelectorAll("fieldset#comfort")) comfortClock(box);
});
