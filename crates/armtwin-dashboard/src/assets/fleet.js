// The fleet page: one live stream of the page of rows it shows (filter, sort and paging are
// the server's), re-opened whenever the view changes.
const PAGE_ROWS = 100;
const view = { filter: "", sort: "robot", order: "asc", offset: 0 };
let source = null;
let lastPage = null;

const rowsBody = document.getElementById("rows");
const filterInput = document.getElementById("filter");
const filterError = document.getElementById("filter-error");

function fmt(value, scale, digits) {
  return Number.isFinite(value) ? (value * scale).toFixed(digits) : "–";
}

function ageText(ageS) {
  if (ageS === null || ageS === undefined) return "–";
  if (ageS < 1) return "now";
  if (ageS < 120) return `${ageS.toFixed(0)} s ago`;
  if (ageS < 7200) return `${(ageS / 60).toFixed(0)} min ago`;
  return `${(ageS / 3600).toFixed(1)} h ago`;
}

function parentOf(id) {
  const cut = id.lastIndexOf("/");
  return cut < 0 ? "" : id.slice(0, cut);
}

function cell(text, className) {
  const td = document.createElement("td");
  td.textContent = text;
  if (className) td.className = className;
  return td;
}

function render(page) {
  lastPage = page;
  const fragment = document.createDocumentFragment();
  let group = null;
  for (const row of page.rows) {
    // Group headers only make sense while rows are in id order.
    if (view.sort === "robot") {
      const parent = parentOf(row.robot);
      if (parent !== group) {
        group = parent;
        const tr = document.createElement("tr");
        tr.className = "group";
        const td = cell(parent === "" ? "(top level)" : parent + "/");
        td.colSpan = 9;
        tr.appendChild(td);
        fragment.appendChild(tr);
      }
    }
    const tr = document.createElement("tr");
    tr.dataset.robot = row.robot;
    const alarm = row.alarm.position || row.alarm.angle;
    if (alarm) tr.className = "alarm";
    const name = document.createElement("td");
    // Another shard's robot has its page on that instance's dashboard, not here.
    const link = document.createElement(row.local ? "a" : "span");
    if (row.local) link.href = "/robot/" + row.robot.split("/").map(encodeURIComponent).join("/");
    link.textContent = view.sort === "robot" ? row.robot.slice(parentOf(row.robot).length).replace(/^\//, "") : row.robot;
    link.title = row.robot;
    name.appendChild(link);
    tr.appendChild(name);
    tr.appendChild(cell(row.shard ?? "?", row.local ? "shard" : "shard remote"));
    tr.appendChild(cell(fmt(row.position_m, 1000, 3), "num position"));
    tr.appendChild(cell(fmt(row.angle_rad, 1000, 3), "num angle"));
    tr.appendChild(cell(String(row.paired), "num paired"));
    tr.appendChild(cell(String(row.unpaired), "num unpaired"));
    tr.appendChild(cell(String(row.rejected), "num rejected"));
    const alarms = [row.alarm.position ? "position" : "", row.alarm.angle ? "angle" : ""].filter(Boolean);
    tr.appendChild(cell(alarms.length ? alarms.join(", ") : "ok", "alarm-state"));
    tr.appendChild(cell(ageText(row.age_s), "num age"));
    fragment.appendChild(tr);
  }
  rowsBody.replaceChildren(fragment);
  const s = page.service;
  document.getElementById("service").textContent =
    `${s.robots} robots tracked · ${s.inputs} inputs · ${s.poses} poses · ${s.publish_errors} publish errors`;
  document.getElementById("summary").textContent =
    `${page.matched} robots match · ${page.alarms} in alarm` +
    (page.fleet_truncated ? " · some robots of other shards may be missing" : "");
  const first = page.matched === 0 ? 0 : page.offset + 1;
  const last = Math.min(page.offset + page.rows.length, page.matched);
  document.getElementById("page").textContent = `${first}–${last} of ${page.matched}`;
  document.getElementById("prev").disabled = page.offset === 0;
  document.getElementById("next").disabled = page.offset + PAGE_ROWS >= page.matched;
}

function query() {
  const params = new URLSearchParams({ sort: view.sort, order: view.order, offset: view.offset, limit: PAGE_ROWS });
  if (view.filter) params.set("filter", view.filter);
  return params.toString();
}

// Bumped by every open(): an open() that a newer one overtook while it awaited stops there, so
// one stream renders, never two in turn.
let opening = 0;

async function open() {
  const mine = ++opening;
  if (source) source.close();
  source = null;
  filterError.textContent = "";
  // A bad filter is a 400 the stream cannot show: ask once first.
  const response = await fetch("/api/fleet?" + query());
  if (mine !== opening) return;
  if (!response.ok) {
    filterError.textContent = (await response.json()).error;
    rowsBody.replaceChildren();
    return;
  }
  const fleet = await response.json();
  if (mine !== opening) return;
  render(fleet);
  source = new EventSource("/api/fleet/stream?" + query());
  source.onmessage = (message) => render(JSON.parse(message.data));
}

for (const th of document.querySelectorAll("th[data-sort]")) {
  th.addEventListener("click", () => {
    const sort = th.dataset.sort;
    view.order = view.sort === sort && view.order === "asc" ? "desc" : "asc";
    view.sort = sort;
    view.offset = 0;
    for (const other of document.querySelectorAll("th[data-sort]")) other.classList.remove("sorted", "desc");
    th.classList.add("sorted");
    if (view.order === "desc") th.classList.add("desc");
    open();
  });
}
document.querySelector('th[data-sort="robot"]').classList.add("sorted");

let filterTimer = null;
filterInput.addEventListener("input", () => {
  clearTimeout(filterTimer);
  filterTimer = setTimeout(() => {
    view.filter = filterInput.value.trim();
    view.offset = 0;
    open();
  }, 300);
});
document.getElementById("prev").addEventListener("click", () => {
  view.offset = Math.max(0, view.offset - PAGE_ROWS);
  open();
});
document.getElementById("next").addEventListener("click", () => {
  if (lastPage && view.offset + PAGE_ROWS < lastPage.matched) {
    view.offset += PAGE_ROWS;
    open();
  }
});

open();
