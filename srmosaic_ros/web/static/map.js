// The map page of srmosaic_ros: the mosaic and SR layers as XYZ tiles, the aircraft, its footprint and
// track. One script for the map server (settings from map_config.js, status from status.json, updates by
// server-sent events from /events) and the offline page written by `process --tiles` (status inline in
// map_config.js, opened from file://). Nothing is loaded from the internet.
(function () {
  'use strict';
  var config = window.SRMOSAIC_CONFIG || {};
  var layersUrl = config.layers || {mosaic: 'tiles/{z}/{x}/{y}.png', sr: 'sr/{z}/{x}/{y}.png'};
  var server = config.mode === 'server';
  // What the tests and a curious user can read: the latest status and counters of what happened.
  var state = window.srmosaic = {config: config, status: null, version: -1, statusLoads: 0, refreshes: 0,
                                 events: 0, fitted: false};

  document.title = config.title || document.title;
  document.getElementById('title').textContent = config.title || 'srmosaic map';

  var map = L.map('map', {zoomSnap: 0.25, maxZoom: 28});
  state.map = map;
  map.attributionControl.setPrefix('<a href="https://leafletjs.com">Leaflet</a>');
  L.control.scale({imperial: false}).addTo(map);
  map.setView([0, 0], 2);

  function tileLayer(url, zIndex) {
    // ?v= makes a changed tile a new URL (the server's tiles change while a flight goes on)
    return L.tileLayer(server ? url + '?v={v}' : url, {
      v: 0, zIndex: zIndex, minZoom: 0, maxZoom: 28, maxNativeZoom: 18, keepBuffer: 1,
      className: 'srm-layer-' + zIndex, errorTileUrl: '',
      attribution: 'srmosaic_ros'
    });
  }
  var mosaic = tileLayer(layersUrl.mosaic, 1);
  var sr = tileLayer(layersUrl.sr, 2);
  var track = L.geoJSON(null, {style: {color: '#ffd400', weight: 2, opacity: 0.9, className: 'srm-track'}});
  var footprint = L.geoJSON(null, {style: {color: '#00e5ff', weight: 2, fill: true, fillOpacity: 0.08,
                                           className: 'srm-footprint'}});
  var arrow = '<svg width="28" height="28" viewBox="-14 -14 28 28"><path d="M0,-12 L8,10 L0,5 L-8,10 Z" ' +
              'fill="#ff3b30" stroke="#fff" stroke-width="1.5"/></svg>';
  var aircraft = L.marker([0, 0], {
    icon: L.divIcon({className: 'srm-aircraft', html: arrow, iconSize: [28, 28], iconAnchor: [14, 14]}),
    interactive: false, keyboard: false
  });
  var started = false;

  function start(status) {
    mosaic.addTo(map);
    sr.addTo(map);
    track.addTo(map);
    footprint.addTo(map);
    L.control.layers(null, {'Mosaic': mosaic, 'Super-resolved': sr, 'Track': track, 'Footprint': footprint,
                            'Aircraft': aircraft}, {collapsed: true}).addTo(map);
    started = true;
  }

  // maxNative: the deepest zoom the server renders (deeper: its tiles scaled up); below minZoom the layer
  // hides (the SR layer adds nothing where the mosaic's own pixels are smaller than the screen's).
  function setZooms(layer, minZoom, maxNative) {
    if (maxNative === null || maxNative === undefined) return false;
    var changed = layer.options.maxNativeZoom !== maxNative || layer.options.minZoom !== minZoom;
    layer.options.maxNativeZoom = maxNative;
    layer.options.minZoom = minZoom;
    return changed;
  }

  function row(name, value) {
    return '<tr><td>' + name + '</td><td>' + value + '</td></tr>';
  }

  function showInfo(status) {
    var html = '<table>' + row('frames', status.frames === null || status.frames === undefined ? '&ndash;' : status.frames);
    var p = status.pose;
    if (p) {
      html += row('lat, lon', p.lat.toFixed(6) + ', ' + p.lon.toFixed(6));
      if (p.alt !== null && p.alt !== undefined) html += row('altitude', p.alt.toFixed(1) + ' m');
      if (p.heading_deg !== null && p.heading_deg !== undefined) html += row('heading', p.heading_deg.toFixed(0) + '&deg;');
    }
    html += row('source', status.live ? 'live' : 'finished run');
    if (server) html += row('updates', state.events ? 'connected' : 'waiting');
    document.getElementById('info').innerHTML = html + '</table>';
  }

  function applyStatus(status) {
    state.status = status;
    state.statusLoads += 1;
    if (status.bounds) {
      var b = status.bounds;  // [west, south, east, north]
      var box = L.latLngBounds([[b[1], b[0]], [b[3], b[2]]]);
      if (!state.fitted) {
        map.fitBounds(box, {padding: [20, 20], animate: false});
        state.fitted = true;
      }
      // tiles are asked for only inside the mosaic's box; a live mosaic's box grows: ask for the new ones
      var grew = !mosaic.options.bounds || !mosaic.options.bounds.equals(box);
      mosaic.options.bounds = box;
      sr.options.bounds = box;
      if (grew && started) { mosaic._update(); sr._update(); }
    }
    var zooms = setZooms(mosaic, 0, status.maxzoom);
    zooms = setZooms(sr, status.sr_minzoom || 0, status.sr_maxzoom) || zooms;
    if (!started && status.bounds && status.maxzoom !== null && status.maxzoom !== undefined) start(status);
    else if (zooms && started) { mosaic.redraw(); sr.redraw(); }
    track.clearLayers();
    if (status.track) track.addData(status.track);
    footprint.clearLayers();
    if (status.footprint) footprint.addData(status.footprint);
    var p = status.pose;
    if (p && p.lat !== null && p.lon !== null) {
      aircraft.setLatLng([p.lat, p.lon]);
      if (!map.hasLayer(aircraft)) aircraft.addTo(map);
      var svg = aircraft.getElement() && aircraft.getElement().querySelector('svg');
      var heading = p.heading_deg !== null && p.heading_deg !== undefined ? p.heading_deg : 0;
      if (svg) svg.style.transform = 'rotate(' + heading + 'deg)';
    }
    showInfo(status);
  }

  // New URLs for the tiles in view; each <img> keeps its old picture until the new one has loaded.
  function refreshTiles(layer, version) {
    layer.options.v = version;
    for (var key in layer._tiles) {
      var tile = layer._tiles[key];
      if (tile.el && tile.el.tagName === 'IMG') tile.el.src = layer.getTileUrl(tile.coords);
    }
  }

  function loadStatus() {
    return fetch(config.status_url, {cache: 'no-store'}).then(function (r) {
      if (!r.ok) throw new Error('status.json: HTTP ' + r.status);
      return r.json();
    }).then(applyStatus).catch(function (err) {
      document.getElementById('info').textContent = String(err);
    });
  }

  if (server) {
    loadStatus();
    if (config.events_url && window.EventSource) {
      var events = new EventSource(config.events_url);
      events.addEventListener('version', function (e) {
        var version = JSON.parse(e.data).version;
        state.events += 1;
        if (version <= state.version) return;
        state.version = version;
        refreshTiles(mosaic, version);
        refreshTiles(sr, version);
        state.refreshes += 1;
        loadStatus();
      });
    }
  } else if (config.status) {
    applyStatus(config.status);
  }
})();
