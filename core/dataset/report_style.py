"""The triage report's inline style sheet and its one script (click a column head to sort the table)."""

CSS = """
:root{--fg:#1d2330;--dim:#6b7280;--line:#e3e6ec;--bg:#f6f7f9;--card:#fff;--bad:#c0392b;--warn:#d97706;
--ok:#15803d;--acc:#2563eb;--holes:#f59e0b;--outside:#94a3b8}
*{box-sizing:border-box}
body{margin:0;background:var(--bg);color:var(--fg);font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,
"DejaVu Sans",sans-serif}
main{max-width:1180px;margin:0 auto;padding:24px 28px 40px}
header h1{margin:0 0 6px;font-size:24px;font-weight:650}
header .ds{color:var(--acc)}
ul.facts{display:flex;flex-wrap:wrap;gap:8px;list-style:none;margin:0;padding:0}
ul.facts li{background:var(--card);border:1px solid var(--line);border-radius:14px;padding:2px 10px;font-size:13px}
ul.facts li.bad{border-color:var(--bad);color:var(--bad);font-weight:600}
section{background:var(--card);border:1px solid var(--line);border-radius:10px;padding:14px 18px;margin:18px 0}
h2{font-size:18px;margin:0 0 10px}
ol.ranked,ol.scenes-first{margin:0;padding:0;list-style:none;counter-reset:r}
ol.ranked li,ol.scenes-first>li{counter-increment:r;display:flex;align-items:baseline;gap:8px;padding:5px 0;
border-top:1px solid var(--line)}
ol.ranked li:first-child,ol.scenes-first>li:first-child{border-top:0}
ol.ranked li::before,ol.scenes-first>li::before{content:counter(r) ".";color:var(--dim);width:22px;text-align:right;
font-variant-numeric:tabular-nums}
a.scene{font-weight:600;color:var(--acc);text-decoration:none}
a{color:var(--acc)}
.tag{background:#eef2ff;color:#3730a3;border-radius:4px;padding:0 6px;font-size:12px}
.reason{flex:1}
ol.scenes-first>li{flex-wrap:wrap;align-items:flex-start}
ul.reasons{flex:1;margin:0;padding-left:18px;min-width:280px}
ul.reasons li{padding:1px 0}
p.since{margin:0 0 8px;color:var(--dim)}
img.mini{width:173px;image-rendering:pixelated;border:1px solid var(--line)}
div.filter{display:flex;gap:14px;align-items:center;margin:0 0 8px}
div.filter input[type=search]{flex:0 1 420px;padding:4px 8px;border:1px solid var(--line);border-radius:6px}
#shown{color:var(--dim);font-size:12px}
div.thumbs{display:flex;flex-wrap:wrap;gap:12px;margin:8px 0}
figure.thumb{margin:0;max-width:360px}figure.thumb img{width:346px;image-rendering:pixelated;border:1px solid var(--line)}
figure.thumb figcaption{font-size:12px;color:var(--dim)}p.since ul{margin:2px 0 0;padding-left:18px}
code.next{flex-basis:100%;margin-left:30px;font-size:12px;color:var(--dim);word-break:break-all;cursor:copy}
code.next[data-copied]::after{content:"  copied";color:#1a7f37;font-family:sans-serif}
.sev{display:inline-block;min-width:44px;text-align:center;border-radius:4px;padding:0 4px;font-size:12px;
font-weight:700;color:#fff;font-variant-numeric:tabular-nums}
.sev.fail{background:#7f1d1d}.sev.hi{background:var(--bad)}.sev.mid{background:var(--warn)}.sev.lo{background:#9ca3af}
table{border-collapse:collapse;width:100%}
th,td{padding:4px 8px;border-bottom:1px solid var(--line);text-align:left;vertical-align:middle}
thead th{font-size:12px;color:var(--dim);font-weight:600;white-space:nowrap}
table.sortable thead th{cursor:pointer}
table.sortable thead th:hover{color:var(--acc)}
td.num,th.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
td.bad,td.num.bad{color:var(--bad);font-weight:700}
tr.failed td.err{color:var(--bad)}
.plots{display:flex;flex-wrap:wrap;gap:10px 28px;margin-top:14px}
figure{margin:0}
figcaption{font-size:12px;color:var(--dim);margin-bottom:4px;max-width:520px}
.key{display:inline-block;width:10px;height:10px;border-radius:2px;vertical-align:middle}
.key.holes{background:var(--holes)}.key.outside{background:var(--outside)}
.badge{font-size:12px;border-radius:10px;padding:1px 8px;vertical-align:middle;font-weight:600}
.badge.ok{background:#dcfce7;color:var(--ok)}.badge.warn{background:#fef3c7;color:#92400e}
.badge.fail{background:#fee2e2;color:var(--bad)}
.path{color:var(--dim);font-size:12px;margin:-6px 0 8px;word-break:break-all}
.errbox{background:#fee2e2;color:#7f1d1d;border-radius:6px;padding:8px 12px;font-family:ui-monospace,monospace}
.scene .top{display:grid;grid-template-columns:minmax(0,1fr) 480px;gap:8px 24px;align-items:start}
dl.facts{display:grid;grid-template-columns:130px 1fr;gap:2px 12px;margin:0 0 8px}
dl.facts dt{color:var(--dim)}dl.facts dd{margin:0}
.progress{height:6px;background:var(--line);border-radius:3px;overflow:hidden;max-width:420px;margin-bottom:10px}
.progress div{height:100%;background:var(--ok)}
ul.flags{margin:6px 0 12px;padding:0;list-style:none}
ul.flags li{padding:2px 0}ul.flags .sev{margin-right:8px}
table.objects th.obj{font-weight:650}
ol.worst{margin:0;padding-left:18px;font-size:12px;font-variant-numeric:tabular-nums}
.dim{color:var(--dim)}
.ok{color:var(--ok)}
footer{color:var(--dim);font-size:12px;margin-top:20px}
svg{display:block;font-size:11px}
svg .lbl{fill:var(--fg)}svg .lbl.dim{fill:var(--dim)}svg .lbl.num{font-variant-numeric:tabular-nums}
svg .axis{stroke:#9ca3af}svg .grid{stroke:#eceff3}svg .zero{stroke:#374151;stroke-width:1.2}
svg .bar{fill:#60a5fa}svg .bar.warnbar{fill:#f59e0b}svg .bar.holes{fill:var(--holes)}
svg .bar.outside{fill:var(--outside)}
svg .limit{stroke:var(--bad);stroke-dasharray:4 3;stroke-width:1.2}
svg .median{stroke:#111827;stroke-width:2}
svg .box{fill:#bfdbfe;stroke:#3b82f6}svg .box.warnbox{fill:#fde68a;stroke:#d97706}
svg .whisker{stroke:#6b7280;stroke-width:1.2}
svg .dot{fill:#6b7280}svg .dot.ok{fill:var(--ok)}svg .dot.warn{fill:var(--bad)}svg .dot.unsure{fill:#fff;stroke:var(--warn);stroke-width:2}
svg .err1{stroke:#111827;stroke-width:3}svg .errk{stroke:#9ca3af;stroke-width:1.2}
"""

SORT_JS = r"""
document.querySelectorAll('table.sortable').forEach(function(t){
  t.querySelectorAll('thead th').forEach(function(th,col){
    th.addEventListener('click',function(){
      var body=t.tBodies[0],rows=Array.prototype.slice.call(body.rows),asc=th.dataset.dir!=='asc';
      th.dataset.dir=asc?'asc':'desc';
      function key(r){var c=r.cells[col];if(!c||r.cells.length<=col)return null;var v=c.dataset.sort;
        if(v===undefined||v==='')return null;var n=parseFloat(v);return isNaN(n)?v:n;}
      rows.sort(function(a,b){var x=key(a),y=key(b);if(x===y)return 0;if(x===null)return 1;if(y===null)return -1;
        return (x<y?-1:1)*(asc?1:-1);});
      rows.forEach(function(r){body.appendChild(r);});
    });
  });
});
(function(){
  var q=document.getElementById('scene-filter'),only=document.getElementById('flagged-only'),
      shown=document.getElementById('shown');
  if(!q)return;
  function apply(){
    var words=q.value.toLowerCase().split(/\s+/).filter(Boolean),n=0,all=0;
    document.querySelectorAll('table.filterable tbody tr').forEach(function(r){
      var text=(r.textContent+' '+(r.dataset.reasons||'')).toLowerCase(),ok=true;
      words.forEach(function(w){if(text.indexOf(w)<0)ok=false;});
      if(only.checked&&!(parseInt(r.dataset.flags||'0',10)>0))ok=false;
      r.hidden=!ok;all++;if(ok)n++;
    });
    shown.textContent=(n===all)?'':n+' of '+all+' scenes shown';
  }
  var h=decodeURIComponent(location.hash||'');            // a link like report.html#filter=pose&flagged
  if(h.indexOf('#filter=')===0){var p=h.slice(8).split('&');q.value=p[0];only.checked=p.indexOf('flagged')>0;}
  q.addEventListener('input',apply);only.addEventListener('change',apply);apply();
})();
document.querySelectorAll('code.next').forEach(function(c){   // the next command: a click copies it
  c.setAttribute('role','button');c.title='click to copy: '+c.textContent;
  function select(){var r=document.createRange();r.selectNodeContents(c);
    var s=window.getSelection();s.removeAllRanges();s.addRange(r);}
  function done(){c.dataset.copied='1';setTimeout(function(){delete c.dataset.copied;},1500);}
  c.addEventListener('click',function(){
    if(navigator.clipboard&&navigator.clipboard.writeText)navigator.clipboard.writeText(c.textContent).then(done,select);
    else select();
  });
});
"""
