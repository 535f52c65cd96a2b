// Talking to the daemon: every request carries the token (kept in sessionStorage, never in
// a URL) when there is one; a 401 becomes a NeedsToken error the page shows as such.

const KEY = "elphel-camd-token";
export const API = "/api/v1";

export function token() {
  return sessionStorage.getItem(KEY) || "";
}

export function setToken(value) {
  if (value) sessionStorage.setItem(KEY, value);
  else sessionStorage.removeItem(KEY);
}

export class NeedsToken extends Error {}

export class ApiError extends Error {
  constructor(status, body) {
    super(body.detail || `HTTP ${status}`);
    this.status = status;
    this.body = body;
  }
}

export async function request(path, { method = "GET", body, signal, query } = {}) {
  const headers = {};
  const t = token();
  if (t) headers.Authorization = `Bearer ${t}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const search = new URLSearchParams(query || {}).toString();
  const url = API + path + (search ? `?${search}` : "");
  const answer = await fetch(url, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
    signal,
  });
  if (answer.status === 401) throw new NeedsToken("needs the token");
  if (!answer.ok) {
    let problem = {};
    try {
      problem = await answer.json();
    } catch {
      problem = { detail: `HTTP ${answer.status}` };
    }
    throw new ApiError(answer.status, problem);
  }
  return answer;
}

export async function json(path, options) {
  return (await request(path, options)).json();
}

// A multipart/x-mixed-replace body, part by part: yields {headers, body (Uint8Array)}.
// Each part states its Content-Length, so no scanning for the boundary inside JPEGs.
export async function* multipart(answer) {
  const reader = answer.body.getReader();
  let buffer = new Uint8Array(0);
  const decoder = new TextDecoder();
  const append = (chunk) => {
    const joined = new Uint8Array(buffer.length + chunk.length);
    joined.set(buffer);
    joined.set(chunk, buffer.length);
    buffer = joined;
  };
  const headEnd = () => {
    for (let i = 0; i + 3 < buffer.length; i++) {
      if (buffer[i] === 13 && buffer[i + 1] === 10 && buffer[i + 2] === 13 && buffer[i + 3] === 10) return i;
    }
    return -1;
  };
  for (;;) {
    let end;
    while ((end = headEnd()) < 0) {
      const { value, done } = await reader.read();
      if (done) return;
      append(value);
    }
    const headers = {};
    for (const line of decoder.decode(buffer.subarray(0, end)).split("\r\n")) {
      const at = line.indexOf(":");
      if (at > 0) headers[line.slice(0, at).trim().toLowerCase()] = line.slice(at + 1).trim();
    }
    const length = Number(headers["content-length"]);
    const start = end + 4;
    while (buffer.length < start + length + 2) {
      const { value, done } = await reader.read();
      if (done) return;
      append(value);
    }
    yield { headers, body: buffer.slice(start, start + length) };
    buffer = buffer.slice(start + length + 2);
  }
}

// Server-sent events over fetch (EventSource cannot send the token): yields {type, data}.
export async function* events(answer) {
  const reader = answer.body.pipeThrough(new TextDecoderStream()).getReader();
  let text = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    text += value;
    let cut;
    while ((cut = text.indexOf("\n\n")) >= 0) {
      const block = text.slice(0, cut);
      text = text.slice(cut + 2);
      let type = "message";
      let data = "";
      for (const line of block.split("\n")) {
        if (line.startsWith("event:")) type = line.slice(6).trim();
        else if (line.startsWith("data:")) data += line.slice(5).trim();
      }
      if (data) yield { type, data: JSON.parse(data) };
    }
  }
}
