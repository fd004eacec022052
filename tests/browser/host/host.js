// Mounts the prebuilt Foxglove Studio web app of @foxglove/studio-base (assets/index.js, a UMD
// bundle that expects React 17 and ReactDOM 17 as the globals `react` and `react-dom`), the way
// the upstream web entry (packages/studio-web: index.tsx + Root.tsx) does: install the devtools
// formatters and the fetch override, wait for the fonts, initialise i18n, then render <App> with
// the data sources, an app configuration, a layout storage and the extension loaders.
//
// The upstream web app keeps layouts in IndexedDB and settings in localStorage; this host keeps
// both in memory (each test run starts from a fresh browser profile anyway). Extras for tests and
// for people who open the page by hand:
//   ?layout=/layouts/tank-viz.json   preload that layout into the layout storage and select it
//   ?ds=foxglove-websocket&ds.url=ws://127.0.0.1:8765   (Foxglove's own deep-link parameters)
//   ?ds=remote-file&ds.url=http://127.0.0.1:PORT/data/drive.mcap
// window.__tankviz exposes the state for the test driver (ready, errors).
"use strict";

(function () {
  const state = { ready: false, rendered: false, errors: [] };
  window.__tankviz = state;
  window.addEventListener("error", (event) => state.errors.push(String(event.message)));
  window.addEventListener("unhandledrejection", (event) =>
    state.errors.push(String(event.reason && event.reason.message ? event.reason.message : event.reason)));

  window.react = window.React;
  window["react-dom"] = window.ReactDOM;

  function loadScript(src) {
    return new Promise((resolve, reject) => {
      const script = document.createElement("script");
      script.src = src; // the bundle finds its chunks and wasm beside this URL
      script.onload = () => resolve();
      script.onerror = () => reject(new Error(`cannot load ${src}`));
      document.head.appendChild(script);
    });
  }

  /** IAppConfiguration in memory, with the defaults a test (or a first start) wants. */
  class MemoryAppConfiguration {
    constructor(defaults) {
      this.values = new Map(Object.entries(defaults));
      this.listeners = new Map();
    }
    get(key) {
      return this.values.get(key);
    }
    async set(key, value) {
      this.values.set(key, value);
      for (const cb of this.listeners.get(key) ?? []) {
        cb(value);
      }
    }
    addChangeListener(key, cb) {
      if (!this.listeners.has(key)) {
        this.listeners.set(key, new Set());
      }
      this.listeners.get(key).add(cb);
    }
    removeChangeListener(key, cb) {
      this.listeners.get(key)?.delete(cb);
    }
  }

  /** ILayoutStorage in memory: namespace -> id -> layout. */
  class MemoryLayoutStorage {
    constructor() {
      this.byNamespace = new Map();
    }
    ns(namespace) {
      if (!this.byNamespace.has(namespace)) {
        this.byNamespace.set(namespace, new Map());
      }
      return this.byNamespace.get(namespace);
    }
    async list(namespace) {
      return [...this.ns(namespace).values()];
    }
    async get(namespace, id) {
      return this.ns(namespace).get(id);
    }
    async put(namespace, layout) {
      this.ns(namespace).set(layout.id, layout);
      return layout;
    }
    async delete(namespace, id) {
      this.ns(namespace).delete(id);
    }
    async importLayouts({ fromNamespace, toNamespace }) {
      for (const layout of this.ns(fromNamespace).values()) {
        this.ns(toNamespace).set(layout.id, layout);
      }
      this.ns(fromNamespace).clear();
    }
    async migrateUnnamespacedLayouts() {}
  }

  async function preload(storage, url) {
    const response = await fetch(url);
    if (!response.ok) {
      throw new Error(`layout ${url}: HTTP ${response.status}`);
    }
    const data = await response.json();
    const now = new Date().toISOString();
    const id = `preloaded-${url.replace(/[^A-Za-z0-9]/g, "-")}`;
    const name = url.split("/").pop().replace(/\.json$/, "");
    // The layout manager's local namespace; the storage is fresh, so nothing else is in it.
    await storage.put("local", {
      id,
      name,
      permission: "CREATOR_WRITE",
      baseline: { data, savedAt: now },
      working: undefined,
      syncInfo: undefined,
    });
    // CurrentLayoutProvider selects the profile's current layout at start.
    const profile = JSON.parse(localStorage.getItem("studio.profile-data") ?? "{}");
    localStorage.setItem("studio.profile-data", JSON.stringify({ ...profile, currentLayoutId: id }));
  }

  async function main() {
    await loadScript("/studio/index.js");
    const studio = window; // the UMD bundle copies its exports onto the global object
    const { createElement: h } = window.React;

    studio.installDevtoolsFormatters();
    studio.overwriteFetch();
    await studio.waitForFonts();
    await studio.initI18n();

    const params = new URLSearchParams(window.location.search);
    const layoutStorage = new MemoryLayoutStorage();
    if (params.get("layout")) {
      await preload(layoutStorage, params.get("layout"));
    }
    const S = studio.AppSetting;
    const appConfiguration = new MemoryAppConfiguration({
      [S.TELEMETRY_ENABLED]: false,
      [S.CRASH_REPORTING_ENABLED]: false,
      [S.UPDATES_ENABLED]: false,
      [S.HIDE_SIGN_IN_PROMPT]: true,
      [S.LAUNCH_PREFERENCE]: "web",
      [S.SHOW_OPEN_DIALOG_ON_STARTUP]: false,
      [S.SHOW_DEBUG_PANELS]: false,
      [S.TIMEZONE]: "UTC",
    });
    const dataSources = [
      new studio.Ros1LocalBagDataSourceFactory(),
      new studio.Ros2LocalBagDataSourceFactory(),
      new studio.FoxgloveWebSocketDataSourceFactory(),
      new studio.RosbridgeDataSourceFactory(),
      new studio.UlogLocalDataSourceFactory(),
      new studio.McapLocalDataSourceFactory(),
      new studio.RemoteDataSourceFactory(),
    ];
    const extensionLoaders = [
      new studio.IdbExtensionLoader("org"),
      new studio.IdbExtensionLoader("local"),
    ];

    function Rendered(props) {
      window.React.useEffect(() => {
        state.rendered = true;
      }, []);
      return props.children;
    }

    window.ReactDOM.render(
      h(Rendered, null,
        h(studio.App, {
          deepLinks: [window.location.href],
          dataSources,
          appConfiguration,
          layoutStorage,
          extensionLoaders,
          enableGlobalCss: true,
        })),
      document.getElementById("root"),
    );
    state.ready = true;
  }

  main().catch((error) => {
    state.errors.push(String(error && error.stack ? error.stack : error));
    console.error(error);
  });
})();
