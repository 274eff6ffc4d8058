//! Reading a material's files through its layout: each file's channels are assigned what
//! they hold (a map's component, an alpha, carried data) and decoded as they are stored; the
//! layout is kept so that writing mirrors it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::discover::{file_name, FileRole};
use super::image_file::{read_image, ImageFile};
use crate::layout::{channel_letter, Channel, FileLayout, Holds, Packed, Stored};
use crate::map::Map;
use crate::material::{normals_from_file, Extra, MapKind, OtherSizeFile};
use crate::{Error, Result};

/// Channels of an integer file that differ by at most this are one grey value stored in
/// each (a JPEG's colour conversion can leave a level of difference).
const GREY_TOLERANCE: f32 = 1.0 / 255.0;

/// The maps, carried data and layout read from a material's files, file by file.
#[derive(Default)]
pub(crate) struct Reader {
    pub max_texels: u64,
    /// The components of each map read so far (3 for colour and normals, else 1; a grey
    /// base colour has its one).
    components: BTreeMap<MapKind, Vec<Option<Vec<f32>>>>,
    pub alpha: BTreeMap<MapKind, Map>,
    pub extras: Vec<Extra>,
    pub layout: Vec<FileLayout>,
    /// The size of the maps: the first file's that supplies one, else the first carried
    /// file's (files that supply maps are read first).
    pub size: Option<(usize, usize)>,
    /// Files that supply maps with their sizes, to name them when sizes differ.
    sizes: Vec<(PathBuf, usize, usize)>,
    /// Carried files of another size than the maps, set aside.
    pub other_sizes: Vec<OtherSizeFile>,
    /// What files were read leniently, each note naming its file.
    pub notes: Vec<String>,
    /// Images already decoded, by the path they stand for: read from here, not from disk.
    pub in_memory: BTreeMap<PathBuf, ImageFile>,
}

/// How many components a map of `kind` has.
fn components(kind: MapKind) -> usize {
    match kind {
        MapKind::BaseColor | MapKind::Normal => 3,
        _ => 1,
    }
}

impl Reader {
    pub fn new(max_texels: u64) -> Reader {
        Reader {
            max_texels,
            ..Reader::default()
        }
    }

    /// Whether a map of `kind` has been read.
    pub fn has(&self, kind: MapKind) -> bool {
        self.components.contains_key(&kind)
    }

    /// Reads `path`, which holds what `role` says, recognised as `recognised_as`.
    pub fn read(&mut self, path: &Path, role: &FileRole, recognised_as: &str) -> Result<()> {
        let file = match self.in_memory.remove(path) {
            Some(file) => file,
            None => read_image(path, self.max_texels)?,
        };
        let name = file_stem(path);
        (self.notes).extend(file.notes.iter().map(|n| format!("{name}: {n}")));
        let size = (file.map.width(), file.map.height());
        if let FileRole::Carried { data } = role {
            if *self.size.get_or_insert(size) != size {
                self.other_sizes.push(OtherSizeFile {
                    path: path.to_path_buf(),
                    size: [size.0, size.1],
                    data: *data,
                });
                return Ok(());
            }
        } else {
            self.size.get_or_insert(size);
            self.sizes.push((path.to_path_buf(), size.0, size.1));
        }
        let channels = match role {
            FileRole::Map { role, .. } => {
                let (kind, stored) = role.supplies(file.format.is_float());
                // A second file of a map matup has (a gloss map beside roughness, a file the
                // flags replaced) comes back as data; a normal map in the other convention is
                // written from the normals.
                if self.has(kind) && kind != MapKind::Normal {
                    self.carried_channels(path, &file, true)
                } else {
                    self.map_channels(path, &file, kind, stored)?
                }
            }
            FileRole::Packed(packing) => {
                // Letters spelled each name a channel; a table row's last may be missing.
                let needed = match packing.spelled {
                    true => packing.channels.len(),
                    false => packing.channels.len().min(3),
                };
                if file.map.channels() < needed {
                    return Err(Error::file(
                        path,
                        format!(
                            "a {} file needs {} channels, this one has {}",
                            packing.name,
                            needed,
                            file.map.channels()
                        ),
                    ));
                }
                self.packed_channels(path, &file, &packing.channels)
            }
            FileRole::Carried { data } => self.carried_channels(path, &file, *data),
        };
        self.take(&file.map, &channels);
        self.layout.push(FileLayout {
            path: path.to_path_buf(),
            format: file.format,
            channels,
            recognised_as: recognised_as.to_string(),
        });
        Ok(())
    }

    /// The channels of a file holding a map of `kind`, stored as `stored`.
    fn map_channels(
        &mut self,
        path: &Path,
        file: &ImageFile,
        kind: MapKind,
        stored: Stored,
    ) -> Result<Vec<Channel>> {
        let n = file.map.channels();
        let colour = colour_channels(n);
        let holds = |component| Channel {
            holds: Holds::Map(kind, component),
            stored,
        };
        let mut channels: Vec<Channel> = match (components(kind), colour) {
            (3, 3) => (0..3).map(holds).collect(),
            (1, 1) => vec![holds(0)],
            // Grey base colour: one value for R, G and B.
            (3, 1) if kind == MapKind::BaseColor => vec![holds(0)],
            (1, 3) if same_values(&file.map, &[0, 1, 2]) => vec![holds(0); 3],
            // A grey map in R of an RGB file whose G and B hold something else: kept as data.
            (1, 3) => {
                let mut channels = vec![holds(0)];
                for c in 1..3 {
                    channels.push(self.carry_channel(path, file, c, None));
                }
                channels
            }
            _ => {
                return Err(Error::file(
                    path,
                    format!(
                        "unsupported channel layout for a {kind} map: {n} channel{} (a {kind} \
                         map needs {})",
                        if n == 1 { "" } else { "s" },
                        match kind {
                            MapKind::Normal => "RGB",
                            MapKind::BaseColor => "RGB or grey",
                            _ => "grey or RGB",
                        }
                    ),
                ))
            }
        };
        if colour < n {
            channels.push(if self.alpha.contains_key(&kind) {
                self.carry_channel(path, file, n - 1, None)
            } else {
                Channel {
                    holds: Holds::Alpha(kind),
                    stored: Stored::Linear,
                }
            });
        }
        Ok(channels)
    }

    /// The channels of a file packed as `packing` says: a channel supplies its map unless a
    /// file read before supplied it; every other channel is carried as data.
    fn packed_channels(
        &mut self,
        path: &Path,
        file: &ImageFile,
        packing: &[Packed],
    ) -> Vec<Channel> {
        let mut channels: Vec<Channel> = Vec::new();
        for c in 0..file.map.channels() {
            let packed = packing.get(c).copied().unwrap_or(Packed::Unused);
            let supplied = packed.supplies().filter(|(kind, _)| {
                !self.has(*kind)
                    && !(channels.iter())
                        .any(|ch| matches!(ch.holds, Holds::Map(k, _) if k == *kind))
            });
            channels.push(match supplied {
                Some((kind, stored)) => Channel {
                    holds: Holds::Map(kind, 0),
                    stored,
                },
                None => self.carry_channel(path, file, c, Some(packed)),
            });
        }
        channels
    }

    /// The channels of a file matup carries: grey (or grey in R, G and B) as one grey map;
    /// data as a grey map a channel; colour as RGB, sRGB-decoded in integer files. An alpha
    /// channel is kept with the colour or grey.
    fn carried_channels(&mut self, path: &Path, file: &ImageFile, data: bool) -> Vec<Channel> {
        let n = file.map.channels();
        let colour = colour_channels(n);
        let grey = colour == 1 || same_values(&file.map, &[0, 1, 2]);
        if data && !grey {
            return (0..n)
                .map(|c| self.carry_channel(path, file, c, None))
                .collect();
        }
        let stored = if grey || file.format.is_float() {
            Stored::Linear
        } else {
            Stored::Srgb
        };
        let (w, h) = (file.map.width(), file.map.height());
        let map = if grey {
            let all: Vec<usize> = (0..colour).collect();
            Map::from_planar(w, h, 1, mean_plane(&file.map, &all))
        } else {
            (file.map.select_channels(&[0, 1, 2])).map_values(move |v| stored.decode(0, v))
        };
        let alpha = (colour < n).then(|| file.map.select_channels(&[n - 1]));
        let has_alpha = alpha.is_some();
        let e = self.carry(file_stem(path), path, file, map, alpha);
        let mut channels: Vec<Channel> = (0..colour)
            .map(|c| Channel {
                holds: Holds::Carried(e, if grey { 0 } else { c }),
                stored,
            })
            .collect();
        if has_alpha {
            channels.push(Channel {
                holds: Holds::CarriedAlpha(e),
                stored: Stored::Linear,
            });
        }
        channels
    }

    /// Channel `c` of `file` carried as a grey data map of its own, named by what `packed`
    /// says it holds, else by the file and the channel's letter.
    fn carry_channel(
        &mut self,
        path: &Path,
        file: &ImageFile,
        c: usize,
        packed: Option<Packed>,
    ) -> Channel {
        let letter = channel_letter(file.map.channels(), c);
        let name = match packed {
            Some(p) if p != Packed::Unused => p.name().to_string(),
            _ => format!("{}_{letter}", file_stem(path)),
        };
        let map = file.map.select_channels(&[c]);
        let e = self.carry(name, path, file, map, None);
        Channel {
            holds: Holds::Carried(e, 0),
            stored: Stored::Linear,
        }
    }

    fn carry(
        &mut self,
        name: String,
        path: &Path,
        file: &ImageFile,
        map: Map,
        alpha: Option<Map>,
    ) -> usize {
        self.extras.push(Extra {
            name,
            source: path.to_path_buf(),
            format: file.format,
            map,
            alpha,
        });
        self.extras.len() - 1
    }

    /// Takes the values of the maps (and their alphas) that `channels` of `stored` hold and
    /// no file read before gave. Carried channels were taken as they were assigned.
    fn take(&mut self, stored_map: &Map, channels: &[Channel]) {
        let mut fresh: BTreeMap<MapKind, Vec<Option<Vec<f32>>>> = BTreeMap::new();
        for (i, channel) in channels.iter().enumerate() {
            match channel.holds {
                Holds::Map(kind, component) if !self.has(kind) => {
                    let slots = fresh
                        .entry(kind)
                        .or_insert_with(|| vec![None; components(kind)]);
                    // A grey value stored in R, G and B: their mean, decoded once.
                    let copies: Vec<usize> = (channels.iter().enumerate())
                        .filter(|(_, c)| c.holds == channel.holds)
                        .map(|(j, _)| j)
                        .collect();
                    if slots[component].is_none() && copies[0] == i {
                        let mut values = mean_plane(stored_map, &copies);
                        (values.iter_mut()).for_each(|v| *v = channel.stored.decode(component, *v));
                        slots[component] = Some(values);
                    }
                }
                Holds::Alpha(kind) => {
                    self.alpha.insert(kind, stored_map.select_channels(&[i]));
                }
                _ => {}
            }
        }
        self.components.extend(fresh);
    }

    /// The map of `kind` read, if one was: a grey base colour's value in R, G and B; normals
    /// made unit vectors ([`normals_from_file`]).
    pub fn map(&self, kind: MapKind) -> Option<Map> {
        let (w, h) = self.size?;
        let slots = self.components.get(&kind)?;
        let first = slots[0].as_ref().expect("component 0 is read first");
        let data: Vec<f32> = (0..slots.len())
            .flat_map(|c| slots[c].as_ref().unwrap_or(first).iter().copied())
            .collect();
        let mut map = Map::from_planar(w, h, slots.len(), data);
        if kind == MapKind::Normal {
            normals_from_file(&mut map);
        }
        Some(map)
    }

    /// Refuses maps of different sizes, naming each file and its size.
    pub fn check_sizes(&self, folder: &Path) -> Result<()> {
        let Some((_, w, h)) = self.sizes.first() else {
            return Ok(());
        };
        if self.sizes.iter().all(|(_, sw, sh)| (sw, sh) == (w, h)) {
            return Ok(());
        }
        let list: Vec<String> = (self.sizes.iter())
            .map(|(p, w, h)| format!("{} is {w}×{h}", file_name(p)))
            .collect();
        Err(Error::material(
            folder,
            format!("maps differ in size: {}", list.join(", ")),
        ))
    }
}

/// Whether channels `planes` of `map` hold one value (within [`GREY_TOLERANCE`]).
fn same_values(map: &Map, planes: &[usize]) -> bool {
    if planes.iter().any(|&c| c >= map.channels()) {
        return false;
    }
    let first = map.plane(planes[0]);
    planes[1..]
        .iter()
        .all(|&c| (map.plane(c).iter().zip(first)).all(|(a, b)| (a - b).abs() <= GREY_TOLERANCE))
}

/// The colour (or grey) channels of a file of `n` channels: all but an alpha, which grey +
/// alpha and RGBA files have last.
fn colour_channels(n: usize) -> usize {
    if n.is_multiple_of(2) {
        n - 1
    } else {
        n
    }
}

/// The mean of channels `planes` of `map`: one value stored in several (a JPEG's colour
/// conversion leaves them a level apart).
fn mean_plane(map: &Map, planes: &[usize]) -> Vec<f32> {
    let mut mean = map.plane(planes[0]).to_vec();
    for &c in &planes[1..] {
        (mean.iter_mut().zip(map.plane(c))).for_each(|(m, v)| *m += v);
    }
    if planes.len() > 1 {
        let n = planes.len() as f32;
        mean.iter_mut().for_each(|m| *m /= n);
    }
    mean
}

pub(crate) fn file_stem(path: &Path) -> String {
    path.file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned()
}
