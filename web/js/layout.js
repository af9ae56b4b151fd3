// The studio's layout helpers. The page itself is laid out by CSS (css/app.css): on a window at
// least 821 px wide the canvas sits in a column sized to the window's height and never scrolls
// away, and the panels scroll in their own column beside it, in as many columns as the width left
// allows (1280×720 to 2560×1440). Here: the status line, which a long message (a fit's figures and
// notes) would overflow, opens a panel with the full text of the recent messages.
const HISTORY = 40;

// pack the panels of ``aside`` (a CSS grid of 4 px rows): each spans the rows its height needs,
// kept up to date as panels open, close or change size (a CSS masonry layout is not in browsers yet)
export function packPanels(aside) {
  const fit = (el) => {
    const cs = getComputedStyle(aside), row = parseFloat(cs.gridAutoRows) || 4, gap = parseFloat(cs.rowGap) || 0;
    const h = el.getBoundingClientRect().height + parseFloat(getComputedStyle(el).marginBottom || 0);
    el.style.gridRowEnd = `span ${Math.max(1, Math.ceil((h + gap) / (row + gap)))}`;
  };
  const ro = new ResizeObserver((entries) => entries.forEach((e) => fit(e.target)));
  for (const el of aside.children) ro.observe(el);
  return ro;
}

// status(text): show ``text`` on the status line (its tooltip and the panel have it in full)
export function createStatus(line, panel) {
  const log = [];
  const render = () => {
    panel.innerHTML = "";
    for (const { t, text } of [...log].reverse()) {
      const p = document.createElement("p");
      const time = document.createElement("time");
      time.textContent = t.toLocaleTimeString();
      p.append(time, document.createTextNode(" " + text));
      panel.append(p);
    }
  };
  const toggle = (open = panel.classList.contains("hidden")) => {
    panel.classList.toggle("hidden", !open);
    line.setAttribute("aria-expanded", String(open));
    if (open) render();
  };
  line.setAttribute("role", "button");
  line.setAttribute("tabindex", "0");
  line.setAttribute("aria-controls", panel.id);
  line.setAttribute("aria-expanded", "false");
  line.addEventListener("click", () => toggle());
  line.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); toggle(); } });
  document.addEventListener("keydown", (e) => { if (e.key === "Escape") toggle(false); });
  return (text) => {
    text = String(text);
    line.textContent = text;
    line.title = `${text}\n(click for the recent messages in full)`;
    if (log.length && log[log.length - 1].text === text) return;
    log.push({ t: new Date(), text });
    if (log.length > HISTORY) log.shift();
    if (!panel.classList.contains("hidden")) render();
  };
}
