//! One page of the fleet (`/api/fleet`, its stream and the fleet page): this instance's robots
//! from its own read and the other instances' from the mesh, as one list filtered, sorted and
//! paged here, so a page holds only the rows it shows.
//!
//! Pure: reads the two shared reads, never the twin or the mesh.

use serde::{Deserialize, Serialize};
use zenoh::key_expr::OwnedKeyExpr;

use super::{FleetRead, PeerRead};
use armtwin_core::metrics::Metric;
use armtwin_mesh::zenoh_section::without_source_location;
use armtwin_view::ServiceTotals;

/// Rows one fleet request may ask for.
pub(super) const MAX_PAGE_ROWS: usize = 1000;
/// The longest key expression a fleet filter may be.
const MAX_FILTER_BYTES: usize = 1024;

/// What a fleet page sorts by.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum SortKey {
    #[default]
    Robot,
    Position,
    Angle,
    Paired,
    Unpaired,
    Rejected,
    Alarm,
    Age,
    Shard,
}

#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum Order {
    #[default]
    Asc,
    Desc,
}

/// `?filter=<key expression>&sort=<column>&order=asc|desc&offset=<n>&limit=<n>`.
#[derive(Debug, Deserialize)]
pub(super) struct FleetQuery {
    filter: Option<String>,
    #[serde(default)]
    sort: SortKey,
    #[serde(default)]
    order: Order,
    #[serde(default)]
    offset: usize,
    limit: Option<usize>,
}

/// A checked fleet query.
pub(super) struct FleetSelection {
    filter: Option<OwnedKeyExpr>,
    sort: SortKey,
    order: Order,
    offset: usize,
    pub(super) limit: usize,
}

impl FleetQuery {
    /// The selection, or why the query is refused.
    pub(super) fn check(self) -> Result<FleetSelection, String> {
        let filter = match self.filter.as_deref().map(str::trim) {
            None | Some("") => None,
            Some(text) if text.len() > MAX_FILTER_BYTES => {
                return Err(format!(
                    "the filter is longer than {MAX_FILTER_BYTES} bytes"
                ));
            }
            Some(text) => Some(OwnedKeyExpr::autocanonize(text.to_owned()).map_err(|e| {
                let message = e.to_string();
                let reason = without_source_location(&message);
                format!("the filter is not a key expression: {reason}")
            })?),
        };
        Ok(FleetSelection {
            filter,
            sort: self.sort,
            order: self.order,
            offset: self.offset,
            limit: self.limit.unwrap_or(100).clamp(1, MAX_PAGE_ROWS),
        })
    }
}

#[derive(Serialize)]
struct FleetPage<'a> {
    service: TotalsJson,
    /// The key expression of the robots this instance twins.
    shard: &'a str,
    /// Robots the filter matches, of every instance.
    matched: usize,
    /// Of those, with an alarm active.
    alarms: usize,
    /// Some of the other instances' robots may be missing (more than a read keeps, or an
    /// instance that did not answer in time).
    fleet_truncated: bool,
    offset: usize,
    rows: Vec<PageRow<'a>>,
}

#[derive(Serialize)]
struct TotalsJson {
    inputs: u64,
    poses: u64,
    publish_errors: u64,
    robots: usize,
    max_robots: usize,
    robots_refused: u64,
    robots_retired: u64,
}

impl From<&ServiceTotals> for TotalsJson {
    fn from(totals: &ServiceTotals) -> Self {
        Self {
            inputs: totals.inputs,
            poses: totals.poses,
            publish_errors: totals.publish_errors,
            robots: totals.robots,
            max_robots: totals.max_robots,
            robots_refused: totals.robots_refused,
            robots_retired: totals.robots_retired,
        }
    }
}

/// One robot of the page, whichever instance twins it.
#[derive(Serialize)]
struct PageRow<'a> {
    robot: &'a str,
    /// The key expression of the instance that twins it (`null` if its claim did not answer).
    shard: Option<&'a str>,
    /// Twinned by this instance (its robot page is here).
    local: bool,
    /// Window MAE of the position distance (m).
    position_m: f64,
    /// Window MAE of the rotation angle (rad).
    angle_rad: f64,
    /// Pairs in the window.
    window_n: u64,
    paired: u64,
    unpaired: u64,
    rejected: u64,
    /// Over this instance's life (`null` for another instance's robot).
    poses: Option<u64>,
    alarm: AlarmJson,
    /// Seconds since the twin last had a result of the robot; `null` before its first, and for
    /// another instance's robot.
    age_s: Option<f64>,
    #[serde(skip)]
    key: Option<&'a OwnedKeyExpr>,
}

#[derive(Serialize)]
struct AlarmJson {
    position: bool,
    angle: bool,
}

/// Every robot of both reads: this instance's, then the others' it does not twin itself.
fn rows_of<'a>(read: &'a FleetRead, peers: &'a PeerRead) -> Vec<PageRow<'a>> {
    let (position, angle) = (Metric::Position, Metric::Angle);
    let own = read.rows.iter().zip(&read.keys).map(|(row, key)| {
        let window = &row.metrics.window;
        PageRow {
            robot: &row.id,
            shard: Some(&peers.own_shard),
            local: true,
            position_m: window.of(position).mae,
            angle_rad: window.of(angle).mae,
            window_n: window.n,
            paired: row.metrics.paired,
            unpaired: row.metrics.unpaired,
            rejected: row.metrics.rejected,
            poses: Some(row.counts.poses),
            alarm: AlarmJson {
                position: row.alarms_active.position,
                angle: row.alarms_active.angle,
            },
            age_s: row
                .counts
                .last_active
                .map(|active| read.taken.saturating_duration_since(active).as_secs_f64()),
            key: key.as_ref(),
        }
    });
    let is_own = |id: &str| read.rows.binary_search_by(|row| (*row.id).cmp(id)).is_ok();
    let others = peers
        .fleet
        .rows
        .iter()
        .zip(&peers.keys)
        .filter(|(row, _)| !is_own(&row.id))
        .map(|(row, key)| PageRow {
            robot: &row.id,
            shard: row.shard.as_deref(),
            local: false,
            position_m: row.position_m,
            angle_rad: row.angle_rad,
            window_n: row.window_n,
            paired: row.paired,
            unpaired: row.unpaired,
            rejected: row.rejected,
            poses: None,
            alarm: AlarmJson {
                position: row.alarm_position,
                angle: row.alarm_angle,
            },
            age_s: None,
            key: key.as_ref(),
        });
    own.chain(others).collect()
}

/// The page of the fleet `selection` asks for.
pub(super) fn fleet_page_json(
    read: &FleetRead,
    peers: &PeerRead,
    selection: &FleetSelection,
) -> String {
    let mut matched: Vec<PageRow<'_>> = rows_of(read, peers)
        .into_iter()
        .filter(|row| match (&selection.filter, row.key) {
            (None, _) => true,
            (Some(filter), Some(key)) => filter.intersects(key),
            (Some(_), None) => false,
        })
        .collect();
    let alarms = matched
        .iter()
        .filter(|row| row.alarm.position || row.alarm.angle)
        .count();
    // Rows in id order first: a stable sort keeps it among equals.
    matched.sort_by(|a, b| a.robot.cmp(b.robot));
    match selection.sort {
        SortKey::Robot => {}
        SortKey::Position => matched.sort_by(|a, b| a.position_m.total_cmp(&b.position_m)),
        SortKey::Angle => matched.sort_by(|a, b| a.angle_rad.total_cmp(&b.angle_rad)),
        SortKey::Paired => matched.sort_by_key(|row| row.paired),
        SortKey::Unpaired => matched.sort_by_key(|row| row.unpaired),
        SortKey::Rejected => matched.sort_by_key(|row| row.rejected),
        SortKey::Alarm => {
            matched.sort_by_key(|row| u8::from(row.alarm.position) + u8::from(row.alarm.angle));
        }
        SortKey::Age => matched.sort_by(|a, b| {
            let age = |row: &PageRow<'_>| row.age_s.unwrap_or(f64::INFINITY);
            age(a).total_cmp(&age(b))
        }),
        SortKey::Shard => matched.sort_by_key(|row| row.shard),
    }
    if selection.order == Order::Desc {
        matched.reverse();
    }
    let count = matched.len();
    let rows = matched
        .into_iter()
        .skip(selection.offset)
        .take(selection.limit)
        .collect();
    let page = FleetPage {
        service: TotalsJson::from(&read.totals),
        shard: &peers.own_shard,
        matched: count,
        alarms,
        fleet_truncated: peers.fleet.truncated,
        offset: selection.offset,
        rows,
    };
    serde_json::to_string(&page).unwrap_or_default()
}
