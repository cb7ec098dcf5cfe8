//! Fleet areas: the robots' area graphs merged into one graph of the fleet's places.
//!
//! The same merge as the Python SDK's `lessmap_client.fleet_areas` (its module docstring has
//! the rules and why), checked against the same golden vectors
//! (`schemas/vectors/fleet_areas.json`), so a Rust app and a Python app name the same places:
//!
//! 1. A fleet area stands for robot areas, each named `(robot, area id)`.
//! 2. Without `shared_features` a fleet area is one robot's area.
//! 3. With it, areas of different robots are linked when `|A ∩ B| / min(|A|, |B|) >=
//!    min_containment` and `|A ∩ B| >= min_shared`; links are taken by decreasing Jaccard
//!    (ties: member order) and join two fleet areas only if at least `min_linked_share` of the
//!    cross pairs of different robots are linked and each shares `min_shared` features.
//! 4. Fleet ids count from 0 in the order of each fleet area's first member (robot name, then
//!    area id); across answers a fleet area is named by that first member
//!    ([`FleetGraph::key_of`]).
//! 5. Passages between two fleet areas add up per direction; the boundary features add up
//!    and the `max_boundary_features` most frequent are kept (ties: smaller id).

pub use crate::error::FleetMergeError;
use crate::messages::AreaGraph;
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

/// Boundary features kept per fleet passage (rule 5).
pub const MAX_BOUNDARY_FEATURES: usize = 16;
/// Containment that links two robot areas (rule 3).
pub const MIN_CONTAINMENT: f64 = 0.85;
/// Features two linked robot areas share at least (rule 3).
pub const MIN_SHARED: u64 = 3;
/// Share of the cross pairs that must be linked for two fleet areas to merge (rule 3).
pub const MIN_LINKED_SHARE: f64 = 0.5;

/// How robot areas become fleet areas (rule 3).
#[derive(Clone, Debug, PartialEq)]
pub struct FleetParams {
    /// Feature ids are global across the fleet's robots (fiducials, a shared landmark map).
    pub shared_features: bool,
    /// Containment that links two robot areas, in (0, 1].
    pub min_containment: f64,
    /// Features two linked robot areas share at least, >= 1.
    pub min_shared: u64,
    /// Share of the cross pairs that must be linked for a merge, in (0, 1].
    pub min_linked_share: f64,
    /// Boundary features kept per fleet passage.
    pub max_boundary_features: usize,
}

impl Default for FleetParams {
    fn default() -> Self {
        FleetParams {
            shared_features: false,
            min_containment: MIN_CONTAINMENT,
            min_shared: MIN_SHARED,
            min_linked_share: MIN_LINKED_SHARE,
            max_boundary_features: MAX_BOUNDARY_FEATURES,
        }
    }
}

impl FleetParams {
    /// The defaults with global feature ids: robots in the same place share a fleet area.
    pub fn shared() -> Self {
        FleetParams {
            shared_features: true,
            ..FleetParams::default()
        }
    }

    fn check(&self) -> Result<(), FleetMergeError> {
        for (name, value) in [
            ("min_containment", self.min_containment),
            ("min_linked_share", self.min_linked_share),
        ] {
            if !(value > 0.0 && value <= 1.0) {
                return Err(FleetMergeError::BadParams(format!(
                    "{name} must be in (0, 1], got {value}"
                )));
            }
        }
        if self.min_shared < 1 {
            return Err(FleetMergeError::BadParams(
                "min_shared must be at least 1, got 0".to_owned(),
            ));
        }
        Ok(())
    }
}

/// A robot area: `(robot, area id)`.
pub type Member = (String, u64);

/// One fleet area: the robot areas it stands for, and their sums.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FleetNode {
    /// Fleet area id within this graph.
    pub area: u64,
    /// The robot areas, ascending.
    pub members: Vec<Member>,
    /// Frames over the members.
    pub frames: u64,
    /// Visits over the members.
    pub visits: u64,
    /// Distinct features over the members.
    pub features: u64,
}

/// Passages of any robot between two fleet areas `a < b`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FleetEdge {
    /// The lower fleet area id.
    pub a: u64,
    /// The higher fleet area id.
    pub b: u64,
    /// Passages from `a` to `b`.
    pub a_to_b: u64,
    /// Passages from `b` to `a`.
    pub b_to_a: u64,
    /// Robots that made them, ascending.
    pub robots: Vec<String>,
    /// `(feature id, passages that reported it)`, most frequent first (ties: smaller id).
    pub boundary_features: Vec<(u64, u64)>,
}

impl FleetEdge {
    /// Passages in both directions.
    pub fn passages(&self) -> u64 {
        self.a_to_b + self.b_to_a
    }
}

/// The fleet's areas and passages.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub struct FleetGraph {
    /// Fleet areas by id.
    pub nodes: Vec<FleetNode>,
    /// Passages by `(a, b)`.
    pub edges: Vec<FleetEdge>,
    /// The fleet area of each robot area.
    pub area_of: BTreeMap<Member, u64>,
}

impl FleetGraph {
    /// The name of a robot area's fleet area that outlives this graph: its first member
    /// (rule 4). None for a robot area this graph does not hold.
    pub fn key_of(&self, robot: &str, area: u64) -> Option<&Member> {
        let fleet = *self.area_of.get(&(robot.to_owned(), area))?;
        self.nodes
            .get(usize::try_from(fleet).ok()?)?
            .members
            .first()
    }

    /// The robots that have been in fleet area `area`, ascending.
    pub fn robots_in(&self, area: u64) -> Vec<&str> {
        let Some(node) = usize::try_from(area).ok().and_then(|i| self.nodes.get(i)) else {
            return Vec::new();
        };
        let robots: BTreeSet<&str> = node.members.iter().map(|(r, _)| r.as_str()).collect();
        robots.into_iter().collect()
    }
}

type Pair = (Member, Member);

/// Merge the area graphs of one fleet's robots (one per robot, any order) into the fleet's.
pub fn fleet_graph(
    graphs: &[AreaGraph],
    params: &FleetParams,
) -> Result<FleetGraph, FleetMergeError> {
    params.check()?;
    let fleets: BTreeSet<&str> = graphs.iter().map(|g| g.fleet.as_str()).collect();
    if fleets.len() > 1 {
        return Err(FleetMergeError::SeveralFleets(
            fleets.into_iter().map(String::from).collect(),
        ));
    }
    let mut seen = HashSet::new();
    for graph in graphs {
        if !seen.insert(graph.robot.as_str()) {
            return Err(FleetMergeError::DuplicateRobot(graph.robot.clone()));
        }
    }
    let mut features: BTreeMap<Member, BTreeSet<u64>> = BTreeMap::new();
    let mut sums: HashMap<Member, (u64, u64)> = HashMap::new();
    for graph in graphs {
        for area in &graph.areas {
            let member = (graph.robot.clone(), area.id);
            features.insert(member.clone(), area.features.iter().copied().collect());
            sums.insert(member, (area.frames, area.visits));
        }
    }
    let root = if params.shared_features {
        roots(&features, params)
    } else {
        features.keys().map(|m| (m.clone(), m.clone())).collect()
    };
    let mut area_of: BTreeMap<Member, u64> = BTreeMap::new();
    let mut groups: Vec<Vec<Member>> = Vec::new();
    for member in features.keys() {
        // Ascending: a root is its group's smallest member, so ids follow first members.
        let top = &root[member];
        let fleet_area = match area_of.get(top) {
            Some(&id) => id,
            None => {
                let id = groups.len() as u64;
                groups.push(Vec::new());
                area_of.insert(top.clone(), id);
                id
            }
        };
        area_of.insert(member.clone(), fleet_area);
        groups[fleet_area as usize].push(member.clone());
    }
    let nodes = groups
        .into_iter()
        .enumerate()
        .map(|(index, group)| {
            let distinct: BTreeSet<u64> = group
                .iter()
                .flat_map(|m| features[m].iter().copied())
                .collect();
            FleetNode {
                area: index as u64,
                frames: group.iter().map(|m| sums[m].0).sum(),
                visits: group.iter().map(|m| sums[m].1).sum(),
                features: distinct.len() as u64,
                members: group,
            }
        })
        .collect();
    let edges = fleet_edges(graphs, &area_of, params);
    Ok(FleetGraph {
        nodes,
        edges,
        area_of,
    })
}

/// Each area's fleet area, named by its smallest member (rule 3: links do not chain).
fn roots(features: &BTreeMap<Member, BTreeSet<u64>>, p: &FleetParams) -> HashMap<Member, Member> {
    let shared = shared_counts(features);
    let size = |m: &Member| features[m].len() as u64;
    let mut linked: Vec<(f64, &Pair)> = shared
        .iter()
        .filter(|&(pair, &n)| {
            n >= p.min_shared
                && n as f64 >= p.min_containment * size(&pair.0).min(size(&pair.1)) as f64
        })
        .map(|(pair, &n)| {
            let jaccard = n as f64 / (size(&pair.0) + size(&pair.1) - n) as f64;
            (jaccard, pair)
        })
        .collect();
    let is_link: HashSet<&Pair> = linked.iter().map(|(_, pair)| *pair).collect();
    // Closest pairs first (ties: member order), as the reference sorts by (-jaccard, pair).
    linked.sort_by(|x, y| y.0.total_cmp(&x.0).then_with(|| x.1.cmp(y.1)));
    let mut root: HashMap<Member, Member> =
        features.keys().map(|m| (m.clone(), m.clone())).collect();
    let mut groups: HashMap<Member, Vec<Member>> = features
        .keys()
        .map(|m| (m.clone(), vec![m.clone()]))
        .collect();
    for (_, (x, y)) in linked {
        let (rx, ry) = (root[x].clone(), root[y].clone());
        if rx == ry {
            continue;
        }
        let cross: Vec<Pair> = groups[&rx]
            .iter()
            .flat_map(|a| groups[&ry].iter().map(move |b| (a, b)))
            .filter(|(a, b)| a.0 != b.0)
            .map(|(a, b)| {
                if a < b {
                    (a.clone(), b.clone())
                } else {
                    (b.clone(), a.clone())
                }
            })
            .collect();
        let links = cross.iter().filter(|pair| is_link.contains(pair)).count();
        if (links as f64) < p.min_linked_share * cross.len() as f64 {
            continue;
        }
        if cross
            .iter()
            .any(|pair| shared.get(pair).copied().unwrap_or(0) < p.min_shared)
        {
            continue; // a chain's ends that share nothing stay apart, whatever the share
        }
        let (keep, gone) = if rx < ry { (rx, ry) } else { (ry, rx) };
        let moved = groups.remove(&gone).unwrap_or_default();
        for member in &moved {
            root.insert(member.clone(), keep.clone());
        }
        groups.entry(keep).or_default().extend(moved);
    }
    root
}

/// Features shared by each pair `x < y` of areas of different robots sharing any.
fn shared_counts(features: &BTreeMap<Member, BTreeSet<u64>>) -> BTreeMap<Pair, u64> {
    let mut holders: HashMap<u64, Vec<&Member>> = HashMap::new();
    for (member, set) in features {
        // Ascending members: each holder list is sorted.
        for &feature in set {
            holders.entry(feature).or_default().push(member);
        }
    }
    let mut shared: BTreeMap<Pair, u64> = BTreeMap::new();
    for group in holders.values() {
        for (i, x) in group.iter().enumerate() {
            for y in &group[i + 1..] {
                if x.0 != y.0 {
                    *shared.entry(((*x).clone(), (*y).clone())).or_default() += 1;
                }
            }
        }
    }
    shared
}

fn fleet_edges(
    graphs: &[AreaGraph],
    area_of: &BTreeMap<Member, u64>,
    p: &FleetParams,
) -> Vec<FleetEdge> {
    let mut directed: HashMap<(u64, u64), u64> = HashMap::new();
    let mut makers: BTreeMap<(u64, u64), BTreeSet<String>> = BTreeMap::new();
    let mut boundary: HashMap<(u64, u64), HashMap<u64, u64>> = HashMap::new();
    for graph in graphs {
        for passage in &graph.passages {
            let a = area_of[&(graph.robot.clone(), passage.a)];
            let b = area_of[&(graph.robot.clone(), passage.b)];
            if a == b {
                continue; // one fleet area: a walk inside it
            }
            *directed.entry((a, b)).or_default() += passage.a_to_b;
            *directed.entry((b, a)).or_default() += passage.b_to_a;
            let pair = (a.min(b), a.max(b));
            makers.entry(pair).or_default().insert(graph.robot.clone());
            // A repeated feature in one passage counts once, with its last count (as a map).
            let reported: HashMap<u64, u64> = passage.boundary_features.iter().copied().collect();
            let counts = boundary.entry(pair).or_default();
            for (feature, n) in reported {
                *counts.entry(feature).or_default() += n;
            }
        }
    }
    makers
        .into_iter()
        .map(|((a, b), robots)| {
            let mut ranked: Vec<(u64, u64)> = boundary
                .remove(&(a, b))
                .unwrap_or_default()
                .into_iter()
                .collect();
            ranked.sort_by(|x, y| y.1.cmp(&x.1).then(x.0.cmp(&y.0)));
            ranked.truncate(p.max_boundary_features);
            FleetEdge {
                a,
                b,
                a_to_b: directed.get(&(a, b)).copied().unwrap_or(0),
                b_to_a: directed.get(&(b, a)).copied().unwrap_or(0),
                robots: robots.into_iter().collect(),
                boundary_features: ranked,
            }
        })
        .collect()
}
