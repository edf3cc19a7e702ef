// Small DOM helpers shared by the page's modules.
export const $ = (sel) => document.querySelector(sel);

// el("td", {class: "x", "data-camera": "cam1", onclick: f}, child, "text", ...)
export const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else if (k.startsWith("data-")) node.setAttribute(k, v); else node[k] = v;
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return node;
};
