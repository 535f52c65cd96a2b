// The parameter form, built from the daemon's own description of a port's parameters
// (GET /ports/{port}/params/schema): names, units, limits, meaning and how to show them.
// Every control carries its parameter's Elphel name in `name` and applies on `change`.

import { ApiError, NeedsToken, json } from "./api.js";

const GROUPS = [
  ["Exposure", ["EXPOS", "VEXPOS"]],
  ["Gains", ["GAINR", "GAING", "GAINGB", "GAINB"]],
  ["Window", ["WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT", "BIN_HOR", "BIN_VERT", "FLIPH", "FLIPV"]],
  ["Trigger", ["TRIG", "TRIG_PERIOD", "TRIG_MASTER", "TRIG_DELAY", "TRIG_DECIMATE"]],
  ["Photo-finish", ["PF_HEIGHT"]],
  ["Frame rate", ["FP1000SLIM", "FPSFLAGS"]],
];

const el = (tag, attrs = {}, text) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
};

// Shown value <-> API value (the API keeps Elphel's units: us, 16.16, 10 ns).
const shown = (spec, raw) => (spec.display ? raw * spec.display.factor : raw);
const rawOf = (spec, value) => (spec.display ? Math.round(value / spec.display.factor) : Math.round(value));
const unitOf = (spec) => (spec.display ? spec.display.unit : spec.unit);
const tidy = (x) => (Number.isInteger(x) ? String(x) : String(Number(x.toPrecision(6))));

// A logarithmic slider position 0..1000 <-> raw value.
const SLIDER = 1000;
const toSlider = (spec, raw) => {
  const lo = Math.log(Math.max(spec.minimum, 1));
  const hi = Math.log(Math.max(spec.maximum, 2));
  return Math.round(((Math.log(Math.max(raw, 1)) - lo) / (hi - lo)) * SLIDER);
};
const fromSlider = (spec, pos) => {
  const lo = Math.log(Math.max(spec.minimum, 1));
  const hi = Math.log(Math.max(spec.maximum, 2));
  return Math.round(Math.exp(lo + (pos / SLIDER) * (hi - lo)));
};

export class ParamForm {
  // host: the fieldset; apply(changes) -> Promise<{frame}> sends a PATCH.
  constructor(host, readonlyList, apply) {
    this.host = host;
    this.readonlyList = readonlyList;
    this.apply = apply;
    this.schema = null;
    this.values = {};
    this.pending = new Map(); // name -> frame at which the change is in effect
  }

  build(schema) {
    this.schema = schema;
    this.host.replaceChildren();
    const done = new Set();
    for (const [title, names] of GROUPS) {
      const writable = names.filter((n) => schema.params[n] && schema.params[n].writable);
      if (!writable.length) continue;
      const group = el("fieldset", { class: "group" });
      group.append(el("legend", {}, title));
      for (const name of writable) {
        group.append(this.control(name, schema.params[name]));
        done.add(name);
      }
      this.host.append(group);
    }
    this.readonlyList.replaceChildren();
    for (const [name, spec] of Object.entries(schema.params)) {
      if (spec.writable || done.has(name)) continue;
      this.readonlyList.append(el("dt", { title: spec.doc }, name));
      this.readonlyList.append(el("dd", { "data-readonly": name }, "–"));
    }
  }

  control(name, spec) {
    const row = el("div", { class: "param", "data-param": name });
    const id = `p-${name}`;
    const label = el("label", { for: id, title: spec.doc }, `${name} `);
    label.append(el("small", {}, `${spec.doc} [${unitOf(spec)}]`));
    row.append(label);
    let input;
    if (spec.choices && Object.keys(spec.choices).length === 2 && spec.choices["1"] === "on") {
      input = el("input", { type: "checkbox", id, name });
      input.addEventListener("change", () => this.send(name, input.checked ? 1 : 0));
    } else if (spec.choices) {
      input = el("select", { id, name });
      for (const [value, text] of Object.entries(spec.choices)) {
        input.append(el("option", { value }, `${value} ${text}`));
      }
      input.addEventListener("change", () => this.send(name, Number(input.value)));
    } else {
      input = el("input", {
        type: "number",
        id,
        name,
        step: spec.display ? "any" : String(spec.step || 1),
        "aria-describedby": `e-${name}`,
      });
      input.addEventListener("change", () => {
        if (input.value === "") return;
        this.send(name, rawOf(spec, Number(input.value)));
      });
      if (spec.display && spec.display.slider === "log") {
        const slider = el("input", {
          type: "range",
          name,
          min: "0",
          max: String(SLIDER),
          "aria-label": `${name} (logarithmic slider)`,
          "data-role": "slider",
        });
        slider.addEventListener("input", () => {
          input.value = tidy(shown(spec, fromSlider(spec, Number(slider.value))));
        });
        slider.addEventListener("change", () => this.send(name, fromSlider(spec, Number(slider.value))));
        row.append(slider);
      }
    }
    row.append(input);
    row.append(el("span", { class: "range" }, `${tidy(shown(spec, spec.minimum))}..${tidy(shown(spec, spec.maximum))} ${unitOf(spec)}`));
    row.append(el("span", { class: "effect", "data-effect-for": name, role: "status" }));
    row.append(el("span", { class: "error", id: `e-${name}`, "data-error-for": name, role: "alert" }));
    return row;
  }

  async send(name, raw) {
    const error = this.host.querySelector(`[data-error-for="${name}"]`);
    const effect = this.host.querySelector(`[data-effect-for="${name}"]`);
    error.textContent = "";
    effect.textContent = "…";
    try {
      const answer = await this.apply({ [name]: raw });
      this.pending.set(name, answer.frame);
      effect.dataset.frame = String(answer.frame);
      effect.textContent = `frame ${answer.frame}`;
      this.show(answer.params);
    } catch (e) {
      effect.textContent = "";
      if (e instanceof NeedsToken) error.textContent = "needs the token";
      else if (e instanceof ApiError) {
        const b = e.body;
        error.textContent = b.allowed !== undefined
          ? `${b.parameter}=${JSON.stringify(b.value)} refused; allowed: ${b.allowed}`
          : b.detail;
      } else error.textContent = String(e);
      this.show(this.values, { force: true }); // back to the values in effect (the message quotes the refused one)
    }
  }

  // Show parameter values (raw API units) in the controls, except the one being edited.
  show(values, { force = false } = {}) {
    this.values = { ...this.values, ...values };
    if (!this.schema) return;
    for (const [name, raw] of Object.entries(values)) {
      const spec = this.schema.params[name];
      if (!spec) continue;
      for (const input of this.host.querySelectorAll(`[name="${name}"]`)) {
        if (!force && input === document.activeElement && input.type === "number") continue;
        if (input.type === "checkbox") input.checked = Boolean(raw);
        else if (input.dataset.role === "slider") input.value = String(toSlider(spec, raw));
        else input.value = input.tagName === "SELECT" ? String(raw) : tidy(shown(spec, raw));
      }
      const ro = this.readonlyList.querySelector(`[data-readonly="${name}"]`);
      if (ro) ro.textContent = `${tidy(shown(spec, raw))} ${unitOf(spec)}`;
    }
  }

  // The live view reached `frame`: mark changes that are in effect by now.
  reached(frame) {
    for (const [name, at] of this.pending) {
      if (frame >= at) {
        const effect = this.host.querySelector(`[data-effect-for="${name}"]`);
        if (effect) {
          effect.textContent = `in effect from frame ${at}`;
          effect.dataset.inEffect = "true";
        }
        this.pending.delete(name);
      }
    }
  }
}

export async function loadSchema(port) {
  return json(`/ports/${port}/params/schema`);
}
